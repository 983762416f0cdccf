import pytest

from sssbake.pipeline.config import EMPTY_CONFIG, ConfigError, load_config
from sssbake.pipeline.options import BAKE_DEFAULTS

CONFIG = """
[defaults]
material = "marble"
scale_mm = 2.0

[[assets]]
glob = "thin_*.obj"
material = "skin1"
scale_mm = 0.5

[[assets]]
glob = "sub/*.ply"
atlas_resolution = 256

[materials]
"Wax*" = { albedo = [0.8, 0.7, 0.6], mean_free_path_mm = [2.0, 1.0, 0.5] }
"Tyre" = "opaque"
"""


def test_precedence(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(CONFIG)
    cfg = load_config(path)
    plain = cfg.options_for("a.obj", {})
    assert (plain.material, plain.scale_mm, plain.atlas_resolution) == ("marble", 2.0, BAKE_DEFAULTS.atlas_resolution)
    flagged = cfg.options_for("a.obj", {"scale_mm": 3.0})
    assert flagged.scale_mm == 3.0  # flags beat [defaults]
    thin = cfg.options_for("x/thin_leaf.obj", {"scale_mm": 3.0})
    assert (thin.material, thin.scale_mm) == ("skin1", 0.5)  # [[assets]] rules beat flags
    assert cfg.options_for("sub/a.ply", {}).atlas_resolution == 256
    assert dict(plain.materials)["Tyre"] == "opaque"


@pytest.mark.parametrize(
    "text,needle",
    [
        ("[defaults]\nscale = 1\n", "unknown option"),
        ("[default]\nscale_mm = 1\n", "unknown section"),
        ("[defaults]\nscale_mm = -1\n", "scale_mm"),
        ("[[assets]]\nmaterial = 'skin1'\n", "glob"),
        ("[[assets]]\nglob = '*'\natlas_resolution = 3\n", "atlas_resolution"),
        ("[defaults\n", "invalid TOML"),
        # TOML's own kinds where the option means another: Python would take true for 1 and 512.5 as a size
        ("[defaults]\nscale_mm = true\n", "scale_mm must be a number, got True"),
        ("[defaults]\natlas_resolution = 512.5\n", "atlas_resolution must be a whole number, got 512.5"),
        ("[defaults]\nvalidate = 1\n", "validate must be true or false, got 1"),
        ("[defaults]\nprt_mode = 3\n", "prt_mode must be a string, got 3"),
        ("[[assets]]\nglob = '*'\nprt_directions = 200.0\n", "prt_directions must be a whole number"),
    ],
)
def test_bad_configs_fail_early_with_one_line(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=needle) as e:
        load_config(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "none.toml")


def test_empty_config_gives_defaults():
    assert EMPTY_CONFIG.options_for("a.obj", {}) == BAKE_DEFAULTS
