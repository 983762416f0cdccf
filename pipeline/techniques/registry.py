"""The techniques sssbake knows, in the order the CLI, the report and ``--techniques`` list them.

A new technique is a new ``techniques/<name>/`` package and one line in `ENTRIES`. One that lives
outside the package (a plugin, a test's) is named in the environment variable `PLUGINS_VARIABLE`
(``module:Class``, comma-separated): every process of a batch (forkserver workers, Dask workers)
inherits it, and `BakeOptions`' fields are made from this list when first imported.

`ENTRIES` and `NAMES` import no technique's implementation (`entry.TechniqueEntry`): the options, the
config and the CLI's flags read them, and ``sssbake bake --help`` starts without numpy, scipy and
numba. `technique`, `TECHNIQUES` and `BY_NAME` import the implementations, on first use.
"""

from __future__ import annotations

import importlib
import os
from functools import cache

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.entry import TechniqueEntry
from sssbake.pipeline.techniques.kernels.entry import KernelsEntry
from sssbake.pipeline.techniques.lpv.entry import LpvEntry
from sssbake.pipeline.techniques.prt.entry import PrtEntry
from sssbake.pipeline.techniques.screen.entry import ScreenEntry
from sssbake.pipeline.techniques.spectral.entry import SpectralEntry

PLUGINS_VARIABLE = "SSSBAKE_TECHNIQUES"


def _plugins() -> tuple[TechniqueEntry, ...]:
    """The techniques `PLUGINS_VARIABLE` names, each made with no arguments."""
    specs = [s for s in (s.strip() for s in os.environ.get(PLUGINS_VARIABLE, "").split(",")) if s]
    if not specs:
        return ()
    # the protocol's module imports numpy: only where a plugin is named
    from sssbake.pipeline.techniques.technique import Technique

    found = []
    for spec in specs:
        module, _, name = spec.partition(":")
        try:
            made = getattr(importlib.import_module(module), name)()
        except (ImportError, AttributeError, TypeError, ValueError) as e:
            raise SssbakeError(f"{PLUGINS_VARIABLE}: cannot load technique {spec!r}: {e}") from None
        if not isinstance(made, Technique):
            raise SssbakeError(f"{PLUGINS_VARIABLE}: {spec!r} is not a Technique")
        found.append(made)
    return tuple(found)


#: Every technique's entry: the built-in ones', then the plugins (each its own entry).
ENTRIES: tuple[TechniqueEntry, ...] = (PrtEntry(), KernelsEntry(), SpectralEntry(), ScreenEntry(), LpvEntry()
                                       ) + _plugins()
_ENTRY_BY_NAME: dict[str, TechniqueEntry] = {e.name: e for e in ENTRIES}
NAMES: tuple[str, ...] = tuple(_ENTRY_BY_NAME)
if len(NAMES) < len(ENTRIES) or {"auto", "none"} & set(NAMES):
    raise SssbakeError(f"{PLUGINS_VARIABLE}: a technique's name is taken: {[e.name for e in ENTRIES]}")


def entry(name: str) -> TechniqueEntry:
    """The entry of the registered technique called `name`; ValueError naming the known ones otherwise."""
    try:
        return _ENTRY_BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown technique {name!r}; available: {list(NAMES)}") from None


@cache
def technique(name: str):
    """The registered technique called `name` (a `technique.Technique`), its implementation imported
    on the first call; ValueError naming the known ones otherwise."""
    found = entry(name)
    if found.implementation is None:  # a plugin: its entry is the technique
        return found
    module, _, cls = found.implementation.partition(":")
    return getattr(importlib.import_module(module), cls)()


def __getattr__(attribute: str):
    """`TECHNIQUES` (every registered technique, in `NAMES`' order) and `BY_NAME` (name -> technique):
    made on first use, which imports every implementation."""
    if attribute == "TECHNIQUES":
        value = tuple(technique(n) for n in NAMES)
    elif attribute == "BY_NAME":
        value = {n: technique(n) for n in NAMES}
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {attribute!r}")
    globals()[attribute] = value
    return value
