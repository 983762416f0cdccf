"""The batch config file (TOML): defaults, per-file rules and material-name rules.

```toml
[defaults]                 # every asset; command-line flags override these
material = "marble"
scale_mm = 10.0

[[assets]]                 # per-file rules, matched on the path relative to the input folder;
glob = "thin_*.obj"        # every matching rule applies in order and beats flags and defaults
scale_mm = 1.0
material = "skin1"

[materials]                # source material names (case-insensitive globs), first match wins
"Wax*" = { albedo = [0.85, 0.75, 0.6], mean_free_path_mm = [3.0, 2.0, 1.2], eta = 1.45 }
"Tyre" = "opaque"
```
"""

from __future__ import annotations

import fnmatch
import tomllib
from dataclasses import dataclass
from pathlib import Path

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.options import BAKE_DEFAULTS, BakeOptions, check_options


class ConfigError(SssbakeError, ValueError):
    """The config file is unreadable or holds an unknown or impossible setting."""

    exit_code = 2


@dataclass(frozen=True)
class BatchConfig:
    defaults: dict
    assets: tuple[dict, ...]
    materials: tuple[tuple[str, str | dict], ...]
    source: str = ""

    def options_for(self, rel_path: str, cli_overrides: dict) -> BakeOptions:
        """Options for the asset at `rel_path`: built-in defaults < [defaults] < flags < [[assets]]."""
        try:
            opts = BAKE_DEFAULTS.merged(self.defaults).merged(cli_overrides)
            for rule in self.assets:
                if fnmatch.fnmatch(rel_path, rule["glob"]) or fnmatch.fnmatch(Path(rel_path).name, rule["glob"]):
                    opts = opts.merged(_rule_options(rule))
            opts = opts.merged({"materials": self.materials + opts.materials})
            check_options(opts)
        except ValueError as e:
            where = f"{self.source}: " if self.source else ""
            raise ConfigError(f"{where}{e}") from None
        return opts


def _rule_options(rule: dict) -> dict:
    out = {k: v for k, v in rule.items() if k != "glob"}
    if isinstance(out.get("materials"), dict):
        out["materials"] = tuple(out["materials"].items())
    return out


EMPTY_CONFIG = BatchConfig({}, (), ())


def load_config(path: str | Path) -> BatchConfig:
    """Parse a TOML batch config; raises ConfigError naming the file and the problem."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read config: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    unknown = sorted(set(data) - {"defaults", "assets", "materials"})
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {unknown}; use [defaults], [[assets]], [materials]")
    assets = data.get("assets", [])
    if not isinstance(assets, list) or not all(isinstance(a, dict) and "glob" in a for a in assets):
        raise ConfigError(f"{path}: every [[assets]] rule needs a 'glob'")
    materials = data.get("materials", {})
    if not isinstance(materials, dict):
        raise ConfigError(f"{path}: [materials] must be a table of name pattern = material")
    cfg = BatchConfig(data.get("defaults", {}), tuple(assets), tuple(materials.items()), str(path))
    # Surface unknown keys now, not halfway through a batch.
    cfg.options_for("", {})
    for rule in cfg.assets:
        try:
            check_options(BAKE_DEFAULTS.merged(_rule_options(rule)))
        except ValueError as e:
            raise ConfigError(f"{path}: [[assets]] rule {rule['glob']!r}: {e}") from None
    return cfg
