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


@pytest.mark.parametrize("text, needle", [
    # 50,000 nested arrays: tomllib recurses per level
    ("[defaults]\nscale_mm = " + "[" * 50_000 + "]" * 50_000 + "\n",
     "invalid TOML: arrays or inline tables nested deeper than the parser follows (Python's recursion limit"),
    ("[defaults]\nmaterial = " + "{ a = " * 5_000 + "1" + " }" * 5_000 + "\n", "nested deeper than the parser"),
    ("[defaults]\nscale_mm = " + "9" * 5_000 + "\n", "invalid TOML: Exceeds the limit (4300 digits)"),
    ("defaults = 3\n", "[defaults] must be a table of option = value"),
    ("[[assets]]\nglob = 3\n", "[[assets]] rule 1: glob must be a string, got 3"),
    ("assets = { glob = '*' }\n", "every [[assets]] rule needs a 'glob'"),
    ("materials = ['a']\n", "[materials] must be a table"),
    ("[defaults]\ntechniques = { prt = 1 }\n", "[defaults]: techniques must be a list of technique names"),
    ("[defaults]\nmaterials = { 'W*' = 3 }\n", "[defaults]: materials must be a table of name pattern = material"),
    ("[defaults]\nmaterial = { preset = 3 }\n", "[defaults]: material 'material': preset must be a preset's name, "
                                                "got 3"),
    ("[materials]\n'W*' = { sigma_s_prime = 'a', sigma_a = 1 }\n",
     "[materials] 'W*': material 'W*': sigma_s_prime must be numbers, got 'a'"),
    ("[[assets]]\nglob = 'a*'\nmaterials = { 'W*' = { albedo = 0.5, mean_free_path_mm = 0 } }\n",
     "[[assets]] rule 1 (glob 'a*'): material 'W*': mean_free_path_mm must be > 0"),
    ("[[assets]]\nglob = 'a*'\nmaterial = { sigma_s_prime = 1, sigma_a = 1, eta = 2.5 }\n",
     "[[assets]] rule 1 (glob 'a*'): material 'material': eta 2.5 is beyond the Monte Carlo profile's table"),
], ids=lambda v: v[:40] if isinstance(v, str) else None)
def test_hostile_structure_is_one_line(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert str(e.value).startswith(f"{path}: ") and needle in str(e.value) and "\n" not in str(e.value), str(e.value)
    assert len(str(e.value)) < 400  # a quoted value is cut, not the whole 50,000-deep array


def test_a_rule_that_fits_its_own_profile_is_accepted(tmp_path):
    path = tmp_path / "c.toml"  # eta 2.5 is past the Monte Carlo table, within the dipole
    path.write_text("[[assets]]\nglob = 'a*'\nprofile = 'dipole'\nmaterial = { sigma_s_prime = 1, sigma_a = 1, "
                    "eta = 2.5 }\n")
    assert load_config(path).options_for("a.obj", {}).material["eta"] == 2.5


def test_twenty_thousand_rules_resolve_as_in_order_each_match(tmp_path):
    import fnmatch
    from pathlib import PurePath

    rules, names = [], []
    for i in range(20_000):
        if i % 10 == 0:  # a wildcard a tenth of the time, over 50 folders: several match each asset
            rules.append({"glob": f"dir_{i % 50}/*.obj", "atlas_resolution": 64 + i % 1000})
        elif i % 10 == 1:
            rules.append({"glob": f"asset_{i - 1}.obj", "thickness_rays": 1 + i % 64})  # the file name alone
        else:
            rules.append({"glob": f"dir_{i % 50}/asset_{i}.obj", "scale_mm": 1.0 + i % 997})
            names.append(f"dir_{i % 50}/asset_{i}.obj")
    rules.append({"glob": "dir_7/asset_1*.obj", "scale_mm": 0.5})  # last: beats every rule above it
    lines = []
    for rule in rules:
        lines.append("[[assets]]\n" + "".join(f"{k} = {v!r}\n" for k, v in rule.items()))
    path = tmp_path / "many.toml"
    path.write_text("".join(lines).replace("'", '"'))
    config = load_config(path)
    assert len(config.assets) == 20_001
    for name in names[::997] + ["dir_7/asset_17.obj", "dir_7/asset_1157.obj", "dir_3/asset_0.obj"]:
        expected = {}  # the documented precedence: every matching rule in order, a later one winning
        for rule in rules:
            if fnmatch.fnmatch(name, rule["glob"]) or fnmatch.fnmatch(PurePath(name).name, rule["glob"]):
                expected.update({k: v for k, v in rule.items() if k != "glob"})
        options = config.options_for(name, {})
        assert expected and {k: getattr(options, k) for k in expected} == expected, name
    assert config.options_for("dir_7/asset_1157.obj", {"scale_mm": 9.0}).scale_mm == 0.5
