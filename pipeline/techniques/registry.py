"""The techniques sssbake knows, in the order the CLI, the report and ``--techniques`` list them.

A new technique is a new ``techniques/<name>/`` package and one line in `TECHNIQUES`. One that lives
outside the package (a plugin, a test's) is named in the environment variable `PLUGINS_VARIABLE`
(``module:Class``, comma-separated): every process of a batch (forkserver workers, Dask workers)
inherits it, and `BakeOptions`' fields are made from this list when first imported.
"""

from __future__ import annotations

import importlib
import os

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.kernels.technique import Kernels
from sssbake.pipeline.techniques.lpv.technique import Lpv
from sssbake.pipeline.techniques.prt.technique import Prt
from sssbake.pipeline.techniques.screen.technique import Screen
from sssbake.pipeline.techniques.spectral.technique import Spectral
from sssbake.pipeline.techniques.technique import Technique

PLUGINS_VARIABLE = "SSSBAKE_TECHNIQUES"


def _plugins() -> tuple[Technique, ...]:
    """The techniques `PLUGINS_VARIABLE` names, each made with no arguments."""
    found = []
    for spec in filter(None, (s.strip() for s in os.environ.get(PLUGINS_VARIABLE, "").split(","))):
        module, _, name = spec.partition(":")
        try:
            made = getattr(importlib.import_module(module), name)()
        except (ImportError, AttributeError, TypeError, ValueError) as e:
            raise SssbakeError(f"{PLUGINS_VARIABLE}: cannot load technique {spec!r}: {e}") from None
        if not isinstance(made, Technique):
            raise SssbakeError(f"{PLUGINS_VARIABLE}: {spec!r} is not a Technique")
        found.append(made)
    return tuple(found)


TECHNIQUES: tuple[Technique, ...] = (Prt(), Kernels(), Spectral(), Screen(), Lpv()) + _plugins()
BY_NAME: dict[str, Technique] = {t.name: t for t in TECHNIQUES}
NAMES: tuple[str, ...] = tuple(BY_NAME)
if len(NAMES) < len(TECHNIQUES) or {"auto", "none"} & set(NAMES):
    raise SssbakeError(f"{PLUGINS_VARIABLE}: a technique's name is taken: {[t.name for t in TECHNIQUES]}")


def technique(name: str) -> Technique:
    """The registered technique called `name`; ValueError naming the known ones otherwise."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown technique {name!r}; available: {list(NAMES)}") from None
