import json

import numpy as np
import pytest

from sssbake.pipeline.core.profile import total_for_albedo
from sssbake.pipeline.core.materials import (
    Material,
    MaterialError,
    from_albedo_mfp,
    material_from_spec,
    preset,
    preset_names,
)


def test_twelve_presets_match_the_table():
    names = preset_names()
    assert names == sorted(
        ["apple", "chicken1", "chicken2", "cream", "ketchup", "marble", "potato", "skimmilk", "skin1", "skin2",
         "spectralon", "wholemilk"]
    )
    marble = preset("Marble")
    assert marble.sigma_s_prime == (2.19, 2.62, 3.0)
    assert marble.sigma_a == (0.0021, 0.0041, 0.0071)
    assert marble.eta == 1.5
    assert preset("skin1").eta == 1.3


@pytest.mark.parametrize(
    "kwargs,needle",
    [
        (dict(sigma_s_prime=[-1, 1, 1], sigma_a=[0.1] * 3, eta=1.3), ">= 0"),
        (dict(sigma_s_prime=[1, 1, 1], sigma_a=[0.1, float("nan"), 0.1], eta=1.3), "finite"),
        (dict(sigma_s_prime=[1, 1, 1], sigma_a=[0.1] * 3, eta=0.9), "eta"),
        (dict(sigma_s_prime=[1, 1, 1], sigma_a=[0.1] * 3, eta=float("inf")), "eta"),
        (dict(sigma_s_prime=[0, 1, 1], sigma_a=[0, 0.1, 0.1], eta=1.3), "> 0"),
        (dict(sigma_s_prime=[1, 1], sigma_a=[0.1] * 3, eta=1.3), "1 or 3"),
    ],
)
def test_impossible_values_are_rejected(kwargs, needle):
    with pytest.raises(MaterialError, match=needle) as e:
        Material("bad", **kwargs)
    assert "\n" not in str(e.value) and "'bad'" in str(e.value)


def test_unknown_preset_names_the_choices():
    with pytest.raises(MaterialError, match="marble"):
        preset("granite")


@pytest.mark.parametrize("profile", ["montecarlo", "dipole"])
def test_from_albedo_mfp_inverts_the_models_total(profile):
    m = from_albedo_mfp("wax", [0.8, 0.6, 0.3], [2.0, 1.0, 0.5], eta=1.4, profile=profile)
    assert m.profile == profile
    rd = total_for_albedo(m.albedo_prime, m.eta, profile)
    np.testing.assert_allclose(rd, [0.8, 0.6, 0.3], rtol=1e-10)
    np.testing.assert_allclose(m.mean_free_path_mm, [2.0, 1.0, 0.5], rtol=1e-12)
    with pytest.raises(MaterialError, match="outside"):
        from_albedo_mfp("x", [1.2, 0.5, 0.5], [1, 1, 1])
    with pytest.raises(MaterialError, match="outside"):
        from_albedo_mfp("x", [0.0, 0.5, 0.5], [1, 1, 1])
    with pytest.raises(MaterialError, match="> 0"):
        from_albedo_mfp("x", [0.5, 0.5, 0.5], [1, 0, 1])


def test_spec_forms_and_json_round_trip():
    assert material_from_spec("skin2") == preset("skin2")
    assert material_from_spec({"preset": "apple"}) == preset("apple")
    m = material_from_spec({"sigma_s_prime": 1.0, "sigma_a": [0.1, 0.2, 0.3], "eta": 1.4}, "c")
    assert m.sigma_s_prime == (1.0, 1.0, 1.0)
    again = material_from_spec(json.loads(json.dumps(m.to_json())), "c")
    assert again == m
    with pytest.raises(MaterialError, match="unknown keys"):
        material_from_spec({"sigma_s_prime": 1, "sigma_a": 1, "colour": 3})


def test_derived_lengths():
    m = Material("x", [1.0, 2.0, 3.0], [0.0, 0.5, 1.0], 1.3)
    np.testing.assert_allclose(m.mean_free_path_mm, [1.0, 1 / 2.5, 1 / 4.0])
    assert m.diffusion_length_mm[0] == np.inf
    np.testing.assert_allclose(m.diffusion_length_mm[1:], 1 / np.sqrt(3 * np.array([0.5, 1.0]) * [2.5, 4.0]))


def test_escape_gain_travels_with_the_material_record():
    from dataclasses import replace

    m = preset("skin1")
    assert "escape_gain" not in m.to_json()  # a material on its own keeps its old record
    gained = replace(m, escape_gain=(1.3, 1.2, 1.1))
    assert Material.from_json(json.loads(json.dumps(gained.to_json()))) == gained
    assert Material.from_json(m.to_json()).escape_gain == (1.0, 1.0, 1.0)
    both = replace(gained, back_gain=(3.0, 5.0, 12.0))
    assert Material.from_json(json.loads(json.dumps(both.to_json()))) == both
    assert both.half_space == m and "back_gain" not in m.to_json()
    for field in ("escape_gain", "back_gain"):
        for bad in ((0.0, 1.0, 1.0), (float("nan"), 1.0, 1.0), (1.0, 1.0)):
            with pytest.raises(MaterialError, match=field):
                replace(m, **{field: bad})
