"""The batch config file (TOML): defaults, per-file rules and material-name rules.

```toml
[defaults]                 # every asset; command-line flags override these
material = "marble"
scale_mm = 10.0

[[assets]]                 # per-file rules, matched on the path relative to the input folder;
glob = "thin_*.obj"        # every matching rule applies in order (a later rule's value wins)
scale_mm = 1.0             # and beats flags and defaults
material = "skin1"

[materials]                # source material names (case-insensitive globs), first match wins
"Wax*" = { albedo = [0.85, 0.75, 0.6], mean_free_path_mm = [3.0, 2.0, 1.2], eta = 1.45 }
"Tyre" = "opaque"
```

Everything in it is checked when it is loaded (`load_config`), and the command line's flags on top
of it before a batch starts (`BatchConfig.check`): a bad value refuses the whole batch with one line
naming the file, the section or rule, the option and the problem, and nothing is baked.
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path, PurePath

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.core.ranges import shown
from sssbake.pipeline.options import BAKE_DEFAULTS, BakeOptions, check_options, check_value


class ConfigError(SssbakeError, ValueError):
    """The config file is unreadable or holds an unknown or impossible setting."""

    exit_code = 2


class _Rules:
    """Which ``[[assets]]`` rules match a path, each glob compiled once: a glob without wildcards
    (most rules of a long generated config name one file) is a dictionary lookup, the others one
    regular expression each (fnmatch's own, which it would otherwise look up per call)."""

    def __init__(self, globs: list[str]):
        self.literal: dict[str, list[int]] = {}
        self.patterns: list[tuple[int, re.Pattern]] = []
        for i, glob in enumerate(globs):
            glob = os.path.normcase(glob)  # as fnmatch.fnmatch compares
            if any(c in glob for c in "*?["):
                self.patterns.append((i, re.compile(fnmatch.translate(glob))))
            else:
                self.literal.setdefault(glob, []).append(i)

    def matching(self, rel_path: str) -> list[int]:
        """Indices, in order, of the rules whose glob matches `rel_path` or its file name."""
        path = os.path.normcase(rel_path)
        name = os.path.normcase(PurePath(rel_path).name)
        hits = {*self.literal.get(path, ()), *self.literal.get(name, ())}
        hits.update(i for i, p in self.patterns if p.match(path) or p.match(name))
        return sorted(hits)


@dataclass(frozen=True)
class BatchConfig:
    defaults: dict
    assets: tuple[dict, ...]
    materials: tuple[tuple[str, str | dict], ...]
    source: str = ""
    _rules: _Rules = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_rules", _Rules([rule["glob"] for rule in self.assets]))

    def options_for(self, rel_path: str, cli_overrides: dict) -> BakeOptions:
        """Options for the asset at `rel_path`: built-in defaults < [defaults] < flags < [[assets]]
        (every matching rule in order, a later rule's value winning)."""
        rules: dict = {}
        for i in self._rules.matching(rel_path):
            rules.update(_rule_options(self.assets[i]))
        try:
            opts = _with_materials(BAKE_DEFAULTS.merged(self.defaults).merged(cli_overrides).merged(rules),
                                   self.materials)
            check_options(opts)
        except ValueError as e:
            where = f"{self.source}: " if self.source else ""
            raise ConfigError(f"{where}{e}") from None
        return opts

    def check(self, cli_overrides: dict, flags: dict[str, str] | None = None) -> None:
        """Raise ConfigError before a batch starts when the flags in `cli_overrides` are impossible
        on top of ``[defaults]`` and of every ``[[assets]]`` rule: one line naming the flag (`flags`:
        option name -> flag, e.g. ``"--scale-mm"``), or all of them when none fails alone.
        (`load_config` checked each rule on ``[defaults]``.)

        A combination only some assets' rules make (two rules matching the same file, a rule and
        the flags) is checked when that asset's options are made (`options_for`), and fails that
        asset alone: a rule may match no asset of this batch. So do flags that only some rules make
        possible (``--spectral-variant`` where a rule sets ``techniques = ["spectral"]``).
        """
        flags = flags or {}
        named = " ".join(flags.get(k, k) for k in cli_overrides)
        base = BAKE_DEFAULTS.merged(self.defaults)
        for name, value in cli_overrides.items():  # a value of the wrong kind or range, whatever else is set
            try:
                check_value(name, getattr(base.merged({name: value}), name))  # as the flag's text reads
            except ValueError as e:
                raise ConfigError(f"{flags.get(name, name)}: {e}") from None
        try:
            check_options(_with_materials(base.merged(cli_overrides), self.materials))
        except ValueError as e:
            if all(_problem(base, (cli_overrides, _rule_options(rule)), self.materials) for rule in self.assets):
                # the flag that fails the same way alone is named, else all of them
                alone = [n for n in cli_overrides
                         if _problem(base, ({n: cli_overrides[n]},), self.materials) == str(e)]
                raise ConfigError(f"{flags.get(alone[0], alone[0]) if alone else named}: {e}") from None


def _problem(base: BakeOptions, layers: tuple[dict, ...], materials: tuple) -> str | None:
    """Why `base` with `layers` of options on top, in order, and the config's `materials` is
    impossible (`check_options`), None when it is possible."""
    try:
        for layer in layers:
            base = base.merged(layer)
        check_options(_with_materials(base, materials))
    except ValueError as e:
        return str(e)
    return None


def _rule_options(rule: dict) -> dict:
    """The options a rule sets: all but its glob."""
    return {k: v for k, v in rule.items() if k != "glob"}


def _with_materials(options: BakeOptions, materials: tuple) -> BakeOptions:
    """`options` with the config's ``[materials]`` after its own (a rule's ``materials`` comes first);
    ValueError when its own are not a table."""
    check_value("materials", options.materials)
    return options.merged({"materials": materials + options.materials})


def _check_rules(config: BatchConfig, base: BakeOptions, context: str = "") -> None:
    """Raise ConfigError naming the first ``[[assets]]`` rule of `config` that is impossible on top of
    `base`; rules that set the same values are checked once."""
    seen: set[str] = set()
    for i, rule in enumerate(config.assets):
        options = _rule_options(rule)
        try:
            key = json.dumps(rule | {"glob": None}, sort_keys=True, default=str)
        except ValueError:  # a value JSON cannot hold (a number past 4300 digits)
            key = None
        if key in seen:
            continue
        try:
            check_options(_with_materials(base.merged(options), config.materials))
        except ValueError as e:
            raise ConfigError(f"{config.source}: [[assets]] rule {i + 1} (glob {shown(rule['glob'])}){context}: "
                              f"{e}") from None
        if key is not None:
            seen.add(key)


EMPTY_CONFIG = BatchConfig({}, (), ())


def load_config(path: str | Path) -> BatchConfig:
    """Parse a TOML batch config and check every setting in it; raises ConfigError naming the file
    (and the section, rule or material) and the problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read config: {e}") from None
    try:
        data = tomllib.loads(text)
    except RecursionError:  # tomllib parses arrays and inline tables recursively
        raise ConfigError(f"{path}: invalid TOML: arrays or inline tables nested deeper than the parser follows "
                          f"(Python's recursion limit, {sys.getrecursionlimit()} calls)") from None
    except ValueError as e:  # TOMLDecodeError, and a number past Python's 4300 digits
        raise ConfigError(f"{path}: invalid TOML: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    unknown = sorted(set(data) - {"defaults", "assets", "materials"})
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {shown(unknown)}; use [defaults], [[assets]], [materials]")
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ConfigError(f"{path}: [defaults] must be a table of option = value")
    assets = data.get("assets", [])
    if not isinstance(assets, list) or not all(isinstance(a, dict) and "glob" in a for a in assets):
        raise ConfigError(f"{path}: every [[assets]] rule needs a 'glob'")
    for i, rule in enumerate(assets):
        if not isinstance(rule["glob"], str):
            raise ConfigError(f"{path}: [[assets]] rule {i + 1}: glob must be a string, got {shown(rule['glob'])}")
    materials = data.get("materials", {})
    if not isinstance(materials, dict):
        raise ConfigError(f"{path}: [materials] must be a table of name pattern = material")
    cfg = BatchConfig(defaults, tuple(assets), tuple(materials.items()), str(path))
    # Every setting now, not halfway through a batch: [defaults], the material table (under the
    # defaults' profile model), each rule.
    try:
        base = BAKE_DEFAULTS.merged(defaults)
        check_options(base)
    except ValueError as e:
        raise ConfigError(f"{path}: [defaults]: {e}") from None
    for pattern, spec in cfg.materials:
        try:
            check_options(base.merged({"materials": ((pattern, spec),)}))
        except ValueError as e:
            raise ConfigError(f"{path}: [materials] {shown(pattern)}: {e}") from None
    _check_rules(cfg, base)
    return cfg
