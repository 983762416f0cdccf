"""Fuzzing the command line and the batch config (hypothesis): never a traceback.

(a) Command lines drawn from the real parser (`cli.build_parser`): a subcommand, its positionals and
any of its flags, each with values of its kind and the hostile ones (0, negative, NaN, inf, 1e308,
400-digit whole numbers, empty and non-ASCII text, paths that do not exist). `main(argv)` must return
an int or end in argparse's SystemExit(2), and print no traceback. The heavy work is not run:
inputs are an empty folder or paths that do not exist, and `run_batch` is replaced by a stand-in
that makes each asset's options the real way (`BatchConfig.options_for`, which must accept what
`BatchConfig.check` let through) and bakes nothing.

(b) Config files: TOML documents whose tables hold the config's real keys (options, rules, material
specs) with values of any type and the hostile numbers, and raw junk text. `load_config` returns a
config (whose options a batch can then make, or refuse with a ConfigError) or raises a one-line
ConfigError naming the file; any other exception fails.

Examples: ``FUZZ_EXAMPLES`` each (default 200; derandomized, no example database, so CI sees the same
ones every run).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import tempfile
from dataclasses import fields
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sssbake.pipeline.bake.batch as batch
from sssbake.pipeline.cli import build_parser, main
from sssbake.pipeline.config import BatchConfig, ConfigError, load_config
from sssbake.pipeline.core.materials import preset_names
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.techniques.registry import NAMES

EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "200"))
FUZZ = settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
#: Numbers as a flag or a TOML value spells them.
HOSTILE_NUMBERS = ("0", "-0", "-1", "1", "0.5", "nan", "-nan", "inf", "-inf", "1e308", "-1e308", "1e-308", "5e-324",
                   "1e-300", "1e6", "1e-6", "1000001", "9" * 400, "-" + "9" * 400, "2147483648", "18446744073709551616",
                   "3.8", "2.0", "16", "8192", "8193", "4096", "64")
HOSTILE_TEXT = ("", " ", "none", "auto", "opaque", "marble", ",", "prt,,screen", "auto,prt", "none,prt", "é", "😀",
                "\u202e", "a\nb", "\t", "-", "--", "x" * 300, "../..", "/", "nul\x00", "local:0", "local:-1",
                "local:99999999999", "tcp://", "tcp://256.0.0.1:99999", *NAMES, *preset_names())
MISSING = "/nonexistent/sssbake-fuzz"


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


SUBCOMMANDS = _subcommands()


def _value(action: argparse.Action, folder: str) -> st.SearchStrategy[str]:
    """Values for `action`'s argument: its choices, or text of its kind, or anything hostile."""
    hostile = st.sampled_from(HOSTILE_NUMBERS + HOSTILE_TEXT)
    paths = st.sampled_from([folder, MISSING, MISSING + ".glb", MISSING + ".obj", folder + "/missing.toml", "", "."])
    # mostly values the parser takes (one bad one ends a command line in argparse), some that it refuses
    if action.choices:
        valid = st.sampled_from(sorted(str(c) for c in action.choices))
        return st.one_of(valid, valid, valid, hostile)
    if action.type in (int, float) or getattr(action.type, "__name__", "").startswith(("_whole", "_port")):
        numbers = st.sampled_from(HOSTILE_NUMBERS)
        return st.one_of(numbers, numbers, st.floats(allow_nan=True, allow_infinity=True).map(repr),
                         st.integers(-(10**30), 10**30).map(str), hostile)
    return st.one_of(paths, hostile, st.text(max_size=20))


@st.composite
def command_lines(draw, folder: str) -> list[str]:
    """A command line: a subcommand, its positionals, then some of its flags in any order."""
    name = draw(st.sampled_from(sorted(SUBCOMMANDS)))
    parser = SUBCOMMANDS[name]
    argv = [name]
    for action in parser._actions:
        if action.option_strings or action.dest == "help":
            continue
        count = draw(st.integers(1, 2)) if action.nargs == "+" else 1
        argv += [draw(st.sampled_from([folder, MISSING, MISSING + ".glb"]) if action.dest in ("paths", "file", "input")
                      else _value(action, folder)) for _ in range(count)]
    flags = [a for a in parser._actions if a.option_strings and not isinstance(a, argparse._HelpAction)]
    for action in draw(st.lists(st.sampled_from(flags), max_size=4)) if flags else []:
        flag = draw(st.sampled_from(action.option_strings))
        if action.nargs == 0:
            argv.append(flag)
        elif draw(st.booleans()):
            argv += [flag, draw(_value(action, folder))]
        else:  # --flag=value: a value starting with "-" reaches the flag's type this way only
            argv.append(f"{flag}={draw(_value(action, folder))}")
    if name == "bake" and "-o" not in argv and "--out" not in argv:
        argv += ["-o", draw(st.sampled_from([folder + "/out", MISSING]))]
    return argv


def _options_only(paths, out_dir, config, overrides, **kwargs) -> dict:
    """`run_batch` without a bake: the output folder made (as the batch makes it, an `OutputError` when
    it cannot be) and each asset's options made as the batch makes them; an options error
    `BatchConfig.check` let through fails the test (it would fail every asset)."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise batch.OutputError(f"{out_dir}: {e}") from None
    for rel in ("a.obj", "sub/b.glb"):
        config.options_for(rel, overrides)
    return {"assets": [], "ok": 0, "failed": 0, "worse_than_lambert": [], "seconds": 0.0, "temporaries_removed": 0}


def _run(argv: list[str]) -> tuple[int, str]:
    """`main(argv)`'s exit status (argparse's SystemExit code included) and all it printed."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            code = main(argv)
        except SystemExit as e:  # argparse: a usage error (2)
            assert e.code == 2, (argv, e.code)
            code = 2
    return code, out.getvalue()


@pytest.fixture(scope="module")
def empty_folder():
    with tempfile.TemporaryDirectory() as folder:
        yield folder


@FUZZ
@given(data=st.data())
def test_any_command_line_is_an_exit_status_never_a_traceback(data, empty_folder, monkeypatch_module):
    argv = data.draw(command_lines(empty_folder))
    code, printed = _run(argv)
    assert isinstance(code, int) and not isinstance(code, bool), argv
    assert "Traceback" not in printed, (argv, printed)
    for line in printed.splitlines():  # an error is one line of its own
        assert not line.startswith("error: ") or len(line) < 2000, (argv, line)


@pytest.fixture(scope="module")
def monkeypatch_module():
    """`run_batch` replaced for the module (`_options_only`); hypothesis runs a test's examples in one call."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(batch, "run_batch", _options_only)
        yield patch


def test_the_fuzz_reaches_every_subcommand_and_flag(empty_folder):
    """The strategy draws from the real parser: every subcommand and every bake flag is reachable."""
    bake = SUBCOMMANDS["bake"]
    flags = {s for a in bake._actions for s in a.option_strings}
    assert {"--scale-mm", "--config", "--prt-directions", "--lpv-vein-mm", "--asset-memory"} <= flags
    assert {"bake", "plan", "verify", "inspect", "tradeoff", "view", "presets"} <= set(SUBCOMMANDS)


# (b) config files

_SCALARS = st.one_of(st.sampled_from(HOSTILE_NUMBERS).map(lambda t: ("raw", t)),
                     st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**70), 2**70), st.booleans(),
                     st.sampled_from(HOSTILE_TEXT), st.text(max_size=12))
_VALUES = st.recursive(_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                         st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                       max_leaves=12)
_OPTION_NAMES = sorted(f.name for f in fields(BakeOptions))
_SPEC_KEYS = ("sigma_s_prime", "sigma_a", "eta", "albedo", "mean_free_path_mm", "preset", "profile", "name", "scale_mm")
_NUMBERS_OR_RGB = st.one_of(_SCALARS, st.lists(_SCALARS, min_size=1, max_size=4))
_SPECS = st.one_of(st.sampled_from([*preset_names(), "opaque", "Opaque", "granite", ""]),
                   st.dictionaries(st.sampled_from(_SPEC_KEYS), _NUMBERS_OR_RGB, max_size=5), _VALUES)
_SPECS = st.one_of(_SPECS, st.fixed_dictionaries(  # a table that is mostly right
    {"sigma_s_prime": st.floats(0, 2e4), "sigma_a": st.floats(0, 2e4)}, optional={"eta": st.floats(0.5, 5)}),
    st.fixed_dictionaries({"albedo": st.floats(0, 1), "mean_free_path_mm": st.floats(1e-5, 1e7)}))


def _option_value(f) -> st.SearchStrategy:
    """Values for the option field `f`: mostly of its kind (its choices where it has them), some anything."""
    kind = f.type.removesuffix(" | None")
    choices = f.metadata.get("choices")
    if f.name == "material":
        right = _SPECS
    elif f.name == "materials":
        right = st.dictionaries(st.text(max_size=4), _SPECS, max_size=2)
    elif f.name == "techniques":
        right = st.lists(st.sampled_from(NAMES + ("auto", "none")), max_size=3)
    elif f.name == "allow_roots":
        right = st.lists(st.sampled_from([MISSING, "/", ""]), max_size=2)
    elif choices:
        right = st.sampled_from(list(choices))
    elif "range" in f.metadata:  # its ends and between them, as a number of its kind
        allowed = f.metadata["range"]
        low, high = max(allowed.low, -1e300), min(allowed.high, 1e300)
        inside = st.integers(int(low), int(high)) if kind == "int" else st.floats(low, high)
        right = st.one_of(inside, st.sampled_from([allowed.low, allowed.high]).map(int if kind == "int" else float))
    elif kind == "int":
        right = st.one_of(st.integers(-2, 10_000), st.sampled_from([16, 64, 8192, 8193, 2**63]))
    elif kind == "float":
        right = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, 1e-6, 0.5, 1.0, 1e6,
                                                                                           1e308, 5e-324]))
    elif kind == "bool":
        right = st.booleans()
    else:
        right = st.sampled_from(["montecarlo", "dipole", "homogeneous", "marble", ""])
    return st.one_of(right, right, right, _VALUES)


_OPTIONS = st.lists(st.one_of(*(st.tuples(st.just(f.name), _option_value(f)) for f in fields(BakeOptions)),
                              st.tuples(st.just("bogus"), _VALUES)), max_size=5).map(dict)
_GLOBS = st.one_of(st.sampled_from(["*", "*.obj", "a.obj", "sub/*", "[", "**", ""]), st.text(max_size=8))
_RULE = st.builds(lambda glob, options: {"glob": glob, **options}, _GLOBS, _OPTIONS)
_RULES = st.lists(st.one_of(_RULE, _RULE, _RULE, st.builds(lambda glob, options: {"glob": glob, **options}, _SCALARS,
                                                           _OPTIONS), _OPTIONS, _VALUES), max_size=4)
_DOCUMENT = st.fixed_dictionaries({}, optional={
    "defaults": st.one_of(_OPTIONS, _OPTIONS, _OPTIONS, _VALUES), "assets": st.one_of(_RULES, _RULES, _RULES, _VALUES),
    "materials": st.one_of(st.dictionaries(st.text(max_size=6), _SPECS, max_size=3), _VALUES)})
#: Mostly the config's own sections, sometimes one it does not have.
_DOCUMENTS = st.one_of(_DOCUMENT, _DOCUMENT, _DOCUMENT, st.builds(lambda d, v: {**d, "extra": v}, _DOCUMENT, _VALUES))


def _toml_key(key: str) -> str:
    return '"' + "".join(_toml_char(c) for c in key) + '"'


def _toml_char(c: str) -> str:
    if c in '"\\':
        return "\\" + c
    if ord(c) < 0x20 or ord(c) == 0x7F or 0xD800 <= ord(c) <= 0xDFFF:
        return f"\\u{ord(c):04x}" if ord(c) < 0xD800 else "?"
    return c


def _toml_value(value) -> str:
    """`value` as a TOML inline value (a ("raw", text) pair as its text: numbers TOML spells itself)."""
    if isinstance(value, tuple) and len(value) == 2 and value[0] == "raw":
        return value[1].replace("-nan", "nan")
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return '"' + "".join(_toml_char(c) for c in value) + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"


def toml_document(document: dict) -> str:
    """`document` as TOML: tables as inline values of top-level keys, rules as an array of tables."""
    lines = []
    for key, value in document.items():
        if key == "assets" and isinstance(value, list) and value and all(isinstance(r, dict) for r in value):
            for rule in value:
                lines.append("[[assets]]")
                lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in rule.items()]
        else:
            lines.insert(0, f"{_toml_key(key)} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def _check_config_text(text: str) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.toml"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        try:
            config = load_config(path)
        except ConfigError as e:
            message = str(e)
            assert message.startswith(f"{path}: ") and "\n" not in message and len(message) < 2000, message
            return
        assert isinstance(config, BatchConfig)
        for rel in ("a.obj", "sub/b.glb", ""):  # a batch makes every asset's options: made or one ConfigError
            try:
                config.options_for(rel, {})
            except ConfigError as e:
                assert "\n" not in str(e), str(e)


@FUZZ
@given(document=_DOCUMENTS)
def test_any_config_tree_loads_or_is_one_config_error(document):
    _check_config_text(toml_document(document))


@FUZZ
@given(text=st.one_of(st.text(max_size=200), st.binary(max_size=200).map(lambda b: b.decode("latin-1")),
                      st.lists(st.sampled_from(["[defaults]", "[[assets]]", "[materials]", "glob = '*'", "scale_mm = ",
                                                "= 1", "[", "]", "{", "}", '"', "'''", "\n", "x.y = 1", "nan", "1e308",
                                                "[" * 600]), max_size=12).map("\n".join)))
def test_any_text_loads_or_is_one_config_error(text):
    _check_config_text(text)
