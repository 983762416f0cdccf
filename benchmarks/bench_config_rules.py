"""A batch config with many ``[[assets]]`` rules: seconds to load it (`config.load_config`, which
checks every rule) and to resolve every asset's options (`BatchConfig.options_for`, as the batch
does per asset).

    python benchmarks/bench_config_rules.py [--rules 1000,20000] [--assets 100] [--kind files|distinct|all]

Each config has ``[defaults]``, a ``[materials]`` table and RULES rules. ``files`` (the default):
one in ten a wildcard (``dir_7/*.obj``) that sets a material, the others one file each
(``dir_7/asset_123.obj``) that set one of 7 scales and an atlas size; ``distinct``: the same, each
file's scale its own (every rule is checked, none shares a verdict); ``all``: every rule
``glob = "*"`` with one of 7 scales, so that every rule applies to every asset. The assets are
files the rules name, spread over the folders.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from sssbake.pipeline.config import load_config

FOLDERS = 50


def config_text(rules: int, kind: str = "files") -> str:
    """A config of `rules` ``[[assets]]`` rules of `kind` (module docstring)."""
    lines = ['[defaults]', 'material = "marble"', 'scale_mm = 1.0', '',
             '[materials]', '"Wax*" = { albedo = [0.88, 0.8, 0.62], mean_free_path_mm = [2.0, 1.4, 0.8] }', '']
    for i in range(rules):
        if kind == "all":
            lines += ['[[assets]]', 'glob = "*"', f'scale_mm = {1.0 + i % 7}', '']
        elif i % 10 == 0:
            lines += ['[[assets]]', f'glob = "dir_{i % FOLDERS}/*.obj"', 'material = "skin1"', '']
        else:
            scale = 1.0 + (i * 1e-5 if kind == "distinct" else i % 7)
            lines += ['[[assets]]', f'glob = "dir_{i % FOLDERS}/asset_{i}.obj"', f'scale_mm = {scale}',
                      f'atlas_resolution = {64 << (i % 3)}', '']
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rules", default="1000,20000", help="comma-separated rule counts")
    parser.add_argument("--assets", type=int, default=100, help="assets resolved per config")
    parser.add_argument("--kind", choices=("files", "distinct", "all"), default="files", help="the rules (docstring)")
    args = parser.parse_args()
    print(f"{'rules':>6} {'assets':>6} {'load s':>8} {'resolve s':>10} {'per asset ms':>13}")
    for rules in (int(r) for r in args.rules.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "many_rules.toml"
            path.write_text(config_text(rules, args.kind))
            t = time.perf_counter()
            config = load_config(path)
            loaded = time.perf_counter() - t
            names = [f"dir_{i % FOLDERS}/asset_{i}.obj" for i in range(1, rules, max(1, rules // args.assets))]
            names = names[:args.assets]
            t = time.perf_counter()
            for name in names:
                config.options_for(name, {})
            resolved = time.perf_counter() - t
        print(f"{rules:>6} {len(names):>6} {loaded:>8.2f} {resolved:>10.2f} {1000 * resolved / len(names):>13.2f}",
              flush=True)


if __name__ == "__main__":
    main()
