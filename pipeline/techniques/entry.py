"""What `registry` knows of a technique before importing it: its name, its options dataclass and its
``sssbake tradeoff`` flags. A built-in technique's implementation (``techniques/<name>/technique.py``)
imports numpy, scipy and numba; `BakeOptions`' fields and the CLI's flags need none of that, so each
built-in technique's entry (``techniques/<name>/entry.py``) imports only its light options module,
and ``sssbake bake --help`` starts without the numerical stack.
"""

from __future__ import annotations

import argparse
from typing import ClassVar


class TechniqueEntry:
    """A registered technique before its implementation is imported; `technique.Technique`, which
    a technique's implementation subclasses together with its entry, adds the rest of the protocol.

    Class attributes
    ----------------
    name : str
        The name in ``--techniques``, in the report's blocks and in ``extras.sssbake``; its options
        are the `BakeOptions` fields, TOML keys and flags ``<name>_<field>`` / ``--<name>-<field>``.
    options_type : type
        Its frozen options dataclass; field defaults are the CLI's and the TOML's defaults.
    implementation : str or None
        ``module:Class`` of the technique (`registry.technique` imports it on first use); None for an
        entry that is the technique itself (a plugin, imported when registered).

    Tradeoff hook
    -------------
    add_tradeoff_arguments(parser: argparse.ArgumentParser)
        The ``sssbake tradeoff`` arguments of its sweep (default none).
    """

    name: ClassVar[str]
    options_type: ClassVar[type]
    implementation: ClassVar[str | None] = None

    def add_tradeoff_arguments(self, parser: argparse.ArgumentParser) -> None:
        return None


def add_sweep_argument(parser: argparse.ArgumentParser, flag: str, kind: type, default: tuple, what: str) -> None:
    """A ``tradeoff`` flag taking the values a sweep runs through, comma-separated (`default` if absent)."""
    def parse(text: str) -> tuple:
        return tuple(kind(v) for v in text.split(","))

    parse.__name__ = f"comma-separated {kind.__name__}"  # argparse names the type in its error
    parser.add_argument(flag, type=parse, default=default, help=f"{what} (default {','.join(map(str, default))})")
