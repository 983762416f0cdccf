"""Scattering materials: user coefficients, the measured presets of Jensen et al. 2001, validation.

Coefficients are in 1/mm (the literature's unit), RGB, float64.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from functools import cache
from importlib import resources

import numpy as np

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.core.profile_models import DEFAULT_PROFILE, PROFILE_MODELS
from sssbake.pipeline.core.ranges import Range, shown


class MaterialError(SssbakeError, ValueError):
    """A material's parameters are impossible or unknown."""


# The ranges a material's numbers may take (docs/ranges.md gives them with the options').
#: Each channel's σ'_s and σ_a. The profile peaks at R_d(0) ≈ 600 σ'_t² per mm² (its shallowest pole
#: lies 1e-3 free paths deep), and past σ'_t ≈ 1e6 the kernels' profile table's relative error test
#: (over at least 1e-300, `profile_table`) overflows on the 20 mm sample sphere: 1e4 (a free path of
#: 0.1 µm, a thousand times the densest preset's) keeps two decades from it.
COEFFICIENT = Range(0.0, 1e4, "R_d(0) ≈ 600 σ'_t² overflows the profile tables' error test past ~1e6", "1/mm")
#: Each channel's σ'_t = σ'_s + σ_a. The profile's radii are searched up to 1e12 mm
#: (`profile.radius_for_energy`), and a profile without absorption keeps the share ~z/r of its
#: energy beyond r (z ~ a free path): for the radius that drops 1e-6 of it (the finest share a
#: table resolves, `screen_table_error`'s floor) to stay inside the search, a free path is at most
#: 1e6 mm. (At 1e-12 /mm screen finds no table; at 1e-50 the escape walk's flight lengths overflow.)
EXTINCTION = Range(1e-6, 2 * COEFFICIENT.high, "a free path beyond 1e6 mm puts the profile's radii past its "
                   "1e12 mm search", "1/mm")
#: ``mean_free_path_mm`` (1/σ'_t) of an albedo spec: `EXTINCTION`'s inverse, within `COEFFICIENT`.
MEAN_FREE_PATH = Range(1.0 / COEFFICIENT.high, 1.0 / EXTINCTION.low, "the inverse of the extinction's range", "mm")
#: η under the dipole (the fallback evaluates the classical dipole for every material): its
#: boundary term A = (1 + F_dr) / (1 - F_dr) is infinite where Jensen's fit F_dr(η) reaches 1, at
#: η = 3.848, and negative (a virtual source above the surface) beyond; diamond is 2.42.
ETA_DIPOLE = Range(1.0, 3.8, "the dipole's boundary term A is infinite at 3.848")


@dataclass(frozen=True)
class Material:
    """A homogeneous scattering material.

    Attributes
    ----------
    name : str
    sigma_s_prime : (3,) float64
        Reduced scattering coefficient per RGB channel, 1/mm.
    sigma_a : (3,) float64
        Absorption coefficient per RGB channel, 1/mm.
    eta : float
        Relative index of refraction (>= 1).
    profile : str
        The diffusion profile model every technique evaluates (`PROFILE_MODELS`).
    escape_gain : (3,) float
        Per channel, how much more of the entering light the object this material fills lets out
        than a flat semi-infinite medium (`mesh.escape_gain`): the profile's values are scaled by
        it. 1 for a material on its own; the bake sets it per mesh for the ``montecarlo`` profile
        to the share that leaves in front of the light it entered from.
    back_gain : (3,) float
        Per channel, the factor on what a receiver gathers from lights behind its tangent plane,
        so that the object lets through what its random walk does (`core.back_share`). 1 for a
        material on its own; set with `escape_gain`.
    """

    name: str
    sigma_s_prime: tuple[float, float, float]
    sigma_a: tuple[float, float, float]
    eta: float
    profile: str = DEFAULT_PROFILE
    escape_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    back_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        s = _rgb(self.sigma_s_prime, "sigma_s_prime", self.name, COEFFICIENT)
        a = _rgb(self.sigma_a, "sigma_a", self.name, COEFFICIENT)
        object.__setattr__(self, "sigma_s_prime", s)
        object.__setattr__(self, "sigma_a", a)
        object.__setattr__(self, "eta", _eta(self.eta, self.name, self.profile))
        for field in ("escape_gain", "back_gain"):
            gain = _rgb(getattr(self, field), field, self.name)
            if min(gain) <= 0.0:
                raise MaterialError(f"material {self.name!r}: {field} must be > 0, got {list(gain)}")
            object.__setattr__(self, field, gain)
        if any(x + y <= 0.0 for x, y in zip(s, a)):
            raise MaterialError(
                f"material {self.name!r}: sigma_s_prime + sigma_a must be > 0 in every channel"
            )
        if any(x + y not in EXTINCTION for x, y in zip(s, a)):
            raise MaterialError(f"material {self.name!r}: sigma_s_prime + sigma_a must be in {EXTINCTION.text()} "
                                f"in every channel (a free path up to {MEAN_FREE_PATH.high:g} mm), got "
                                f"{[x + y for x, y in zip(s, a)]}")

    @property
    def half_space(self) -> "Material":
        """This material without its object's gains: the flat semi-infinite medium's profile."""
        return replace(self, escape_gain=(1.0, 1.0, 1.0), back_gain=(1.0, 1.0, 1.0))

    @property
    def s(self) -> np.ndarray:
        """(3,) float64 reduced scattering coefficient, 1/mm."""
        return np.array(self.sigma_s_prime, dtype=np.float64)

    @property
    def a(self) -> np.ndarray:
        """(3,) float64 absorption coefficient, 1/mm."""
        return np.array(self.sigma_a, dtype=np.float64)

    @property
    def sigma_t_prime(self) -> np.ndarray:
        """(3,) reduced extinction coefficient σ'_t = σ'_s + σ_a, 1/mm."""
        return self.s + self.a

    @property
    def albedo_prime(self) -> np.ndarray:
        """(3,) reduced albedo α' = σ'_s / σ'_t."""
        return self.s / self.sigma_t_prime

    @property
    def sigma_tr(self) -> np.ndarray:
        """(3,) effective transport coefficient σ_tr = sqrt(3 σ_a σ'_t), 1/mm."""
        return np.sqrt(3.0 * self.a * self.sigma_t_prime)

    @property
    def mean_free_path_mm(self) -> np.ndarray:
        """(3,) reduced mean free path 1/σ'_t in mm."""
        return 1.0 / self.sigma_t_prime

    @property
    def diffusion_length_mm(self) -> np.ndarray:
        """(3,) diffusion length 1/σ_tr in mm (inf without absorption)."""
        with np.errstate(divide="ignore"):
            return np.where(self.sigma_tr > 0.0, 1.0 / np.maximum(self.sigma_tr, 1e-300), np.inf)

    @staticmethod
    def from_json(data: dict) -> "Material":
        """The inverse of `to_json`. A record without ``profile`` was written before the Monte Carlo
        profile existed, by the classical dipole."""
        return Material(str(data["name"]), tuple(float(v) for v in data["sigma_s_prime"]),
                        tuple(float(v) for v in data["sigma_a"]), float(data["eta"]), str(data.get("profile", "dipole")),
                        tuple(float(v) for v in data.get("escape_gain", (1.0, 1.0, 1.0))),
                        tuple(float(v) for v in data.get("back_gain", (1.0, 1.0, 1.0))))

    def to_json(self) -> dict:
        out = {
            "name": self.name,
            "sigma_s_prime": list(self.sigma_s_prime),
            "sigma_a": list(self.sigma_a),
            "eta": self.eta,
            "profile": self.profile,
        }
        for field in ("escape_gain", "back_gain"):  # records of a material on its own stay as they were
            if getattr(self, field) != (1.0, 1.0, 1.0):
                out[field] = list(getattr(self, field))
        return out


def _eta(eta, name: str, profile: str) -> float:
    """`eta` as a float, checked for the profile model `profile` (which it is checked against first)."""
    if profile not in PROFILE_MODELS:
        raise MaterialError(f"material {name!r}: profile must be one of {', '.join(PROFILE_MODELS)}, "
                            f"got {shown(profile)}")
    if not (isinstance(eta, (int, float)) and not isinstance(eta, bool) and eta >= 1.0 and math.isfinite(eta)):
        raise MaterialError(f"material {name!r}: eta must be a finite number >= 1, got {shown(eta)}")
    if eta not in ETA_DIPOLE:
        raise MaterialError(f"material {name!r}: eta must be in {ETA_DIPOLE.text()} ({ETA_DIPOLE.why}), got {eta:g}")
    if profile == "montecarlo":
        from sssbake.pipeline.core.montecarlo_profile import ETAS

        if eta > ETAS[-1]:
            raise MaterialError(f"material {name!r}: eta {eta:g} is beyond the Monte Carlo profile's "
                                f"table (1-{ETAS[-1]:g}); use --profile dipole")
    return float(eta)


def _rgb(value, field: str, name: str, allowed: Range | None = None) -> tuple[float, float, float]:
    """`value` (one number or three) as three floats, each finite, >= 0 and in `allowed`."""
    if isinstance(value, (bool, str, bytes)) or (isinstance(value, (list, tuple)) and any(
            isinstance(v, (bool, str, bytes)) for v in value)):  # numpy reads "1" and True as numbers
        raise MaterialError(f"material {name!r}: {field} must be numbers, got {shown(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise MaterialError(f"material {name!r}: {field} must be numbers, got {shown(value)}") from None
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3:
        raise MaterialError(f"material {name!r}: {field} needs 1 or 3 values (RGB), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise MaterialError(f"material {name!r}: {field} must be finite, got {arr.tolist()}")
    if np.any(arr < 0.0):
        raise MaterialError(f"material {name!r}: {field} must be >= 0, got {arr.tolist()}")
    if allowed is not None and not all(float(v) in allowed for v in arr):
        raise MaterialError(f"material {name!r}: {field} must be in {allowed.text()} in every channel, "
                            f"got {arr.tolist()}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@cache
def _table() -> dict:
    text = resources.files("sssbake.pipeline.core").joinpath("data/jensen2001_materials.json").read_text()
    return json.loads(text)["materials"]


def preset_names() -> list[str]:
    """Lower-case names of the 12 measured presets (Jensen et al. 2001)."""
    return sorted(k.lower() for k in _table())


def preset(name: str, profile: str = DEFAULT_PROFILE) -> Material:
    """The measured material `name` (case-insensitive), e.g. ``preset("marble")``, under the
    diffusion profile model `profile`."""
    for key, row in _table().items():
        if key.lower() == name.lower():
            return Material(key.lower(), row["sigma_s_prime"], row["sigma_a"], row["eta"], profile)
    raise MaterialError(f"unknown material preset {shown(name)}; choose one of {', '.join(preset_names())}")


def from_albedo_mfp(name: str, albedo, mfp_mm, eta: float = 1.3, profile: str = DEFAULT_PROFILE) -> Material:
    """A material from a diffuse albedo (total diffuse reflectance R_d) and a mean free path.

    Inverts the profile model's total reflectance R_d(α', η) per channel (it is monotone in α'),
    then sets σ'_t = 1 / mfp.

    Parameters
    ----------
    albedo : (3,) float in (0, 1)
        Wanted total diffuse reflectance per channel.
    mfp_mm : (3,) float > 0
        Reduced mean free path 1/σ'_t in mm.
    """
    from scipy.optimize import brentq

    from sssbake.pipeline.core.profile import total_for_albedo

    rd = np.asarray(_rgb(albedo, "albedo", name))
    mfp = np.asarray(_rgb(mfp_mm, "mean_free_path_mm", name))
    if np.any(mfp <= 0.0):
        raise MaterialError(f"material {name!r}: mean_free_path_mm must be > 0, got {mfp.tolist()}")
    if not all(float(v) in MEAN_FREE_PATH for v in mfp):
        raise MaterialError(f"material {name!r}: mean_free_path_mm must be in {MEAN_FREE_PATH.text()} in every "
                            f"channel, got {mfp.tolist()}")
    eta = _eta(eta, name, profile)
    rd_max = float(total_for_albedo(1.0, eta, profile)[0])
    alphas = []
    for r in rd:
        if not 0.0 < r < rd_max:
            raise MaterialError(
                f"material {name!r}: albedo {r} is outside (0, {rd_max:.4f}), the reachable range at eta={eta}"
            )
        alphas.append(brentq(lambda a, r=r: total_for_albedo(a, eta, profile)[0] - r, 0.0, 1.0, xtol=1e-14))
    alpha = np.array(alphas)
    st = 1.0 / mfp
    return Material(name, alpha * st, (1.0 - alpha) * st, eta, profile)


def material_from_spec(spec: dict | str, name: str = "custom", profile: str = DEFAULT_PROFILE) -> Material:
    """A material from a config value: a preset name, or a table with
    ``preset`` / (``sigma_s_prime``, ``sigma_a``, ``eta``) / (``albedo``, ``mean_free_path_mm``, ``eta``),
    under the diffusion profile model `profile` (an albedo is inverted through it), which a table's
    own ``profile`` overrides."""
    if isinstance(spec, str):
        return preset(spec, profile)
    if not isinstance(spec, dict):
        raise MaterialError(f"material {name!r}: expected a preset name or a table, got {shown(spec)}")
    keys = set(spec) - {"scale_mm", "name", "profile"}
    profile = spec.get("profile", profile)
    if not isinstance(spec.get("name", name), str):
        raise MaterialError(f"material {name!r}: name must be a string, got {shown(spec['name'])}")
    if "preset" in keys:
        extra = keys - {"preset"}
        if extra:
            raise MaterialError(f"material {name!r}: 'preset' cannot be combined with {sorted(extra)}")
        if not isinstance(spec["preset"], str):
            raise MaterialError(f"material {name!r}: preset must be a preset's name, got {shown(spec['preset'])}")
        return preset(spec["preset"], profile)
    if {"sigma_s_prime", "sigma_a"} <= keys:
        extra = keys - {"sigma_s_prime", "sigma_a", "eta"}
        if extra:
            raise MaterialError(f"material {name!r}: unknown keys {sorted(extra)}")
        return Material(spec.get("name", name), spec["sigma_s_prime"], spec["sigma_a"], spec.get("eta", 1.3), profile)
    if {"albedo", "mean_free_path_mm"} <= keys:
        extra = keys - {"albedo", "mean_free_path_mm", "eta"}
        if extra:
            raise MaterialError(f"material {name!r}: unknown keys {sorted(extra)}")
        return from_albedo_mfp(spec.get("name", name), spec["albedo"], spec["mean_free_path_mm"], spec.get("eta", 1.3),
                               profile)
    raise MaterialError(
        f"material {name!r}: give 'preset', or 'sigma_s_prime' + 'sigma_a' [+ 'eta'], "
        f"or 'albedo' + 'mean_free_path_mm' [+ 'eta']; got keys {sorted(keys)}"
    )
