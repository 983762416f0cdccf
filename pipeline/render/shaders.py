"""Load the shipped GLSL (``runtime_shaders/*.glsl``) for a dialect, resolving ``#include``.

The sources carry no ``#version`` line: the same file serves desktop GLSL 3.30 core and GLSL ES
3.00 (WebGL 2, mobile), which differ here only in the version line and precision qualifiers.
"""

from __future__ import annotations

import re
from importlib import resources

DIALECTS = {
    "glsl330": "#version 330 core\n",
    "essl300": "#version 300 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler2D;\n"
               "precision highp isampler2D;\nprecision highp usampler2D;\n",
}
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)


def shader_source(name: str, dialect: str = "glsl330", prelude: str = "") -> str:
    """The text of shader file `name` for `dialect`, includes inlined (each file once).

    Parameters
    ----------
    name : str
        A file in ``runtime_shaders/``, e.g. ``"prt.vert"``.
    dialect : str
        ``"glsl330"`` or ``"essl300"``.
    prelude : str
        Text placed after the version line (e.g. ``#define``s); tests put small drivers here.
    """
    if dialect not in DIALECTS:
        raise ValueError(f"shaders: dialect must be one of {sorted(DIALECTS)}, got {dialect!r}")
    return DIALECTS[dialect] + prelude + _expand(name, set())


def _expand(name: str, seen: set[str]) -> str:
    if name in seen:
        return ""
    seen.add(name)
    try:
        text = resources.files("sssbake.runtime_shaders").joinpath(name).read_text()
    except FileNotFoundError:
        raise ValueError(f"shaders: no shader named {name!r} in runtime_shaders/") from None
    return _INCLUDE.sub(lambda m: _expand(m.group(1), seen), text)
