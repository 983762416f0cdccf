"""The errors sssbake raises for its users: one base class, one-line messages."""

from __future__ import annotations

import os


class SssbakeError(Exception):
    """Base of every error sssbake reports to its users: ``str(e)`` is one line, ``"<path>: <problem>"``
    where a file is concerned. The CLI catches this class once and prints it as ``error: <message>``.

    Subclasses that stand for a kind of Python error also derive from it (``class X(SssbakeError,
    ValueError)``), so that callers catching the Python kind keep working.

    Attributes
    ----------
    exit_code : int
        The CLI's exit status when this error ends a command: 1 (the work failed), or 2 for errors
        in the command's setup (its config, its output folder, its cluster).
    """

    exit_code: int = 1


class AssetError(SssbakeError):
    """A problem with one asset, for the user: ``str(e)`` is ``"<path>: <problem>"`` on one line.

    Parameters
    ----------
    path : str or os.PathLike
        The asset the problem is in.
    problem : str
        What is wrong, e.g. ``"truncated file: expected 1200 vertices, read 37"``; line breaks
        are folded so the message stays on one line in batch logs.
    """

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = os.fspath(path)
        self.problem = "; ".join(line.strip() for line in str(problem).splitlines() if line.strip())
        super().__init__(f"{self.path}: {self.problem}")

    def __reduce__(self):
        # Exception pickles its args (the joined message) by default; batch workers send errors
        # across processes, so rebuild from the two fields instead.
        return (type(self), (self.path, self.problem))


class VerifyError(SssbakeError, ValueError):
    """``sssbake verify`` cannot check this file with this technique (wrong technique, no data)."""


class TradeoffError(SssbakeError, ValueError):
    """``sssbake tradeoff`` cannot sweep this input (no unit to scale it by, no mesh)."""


class StaleDataError(AssetError, ValueError):
    """A file's sssbake data no longer matches the glTF data it points at (another tool renumbered,
    deleted or rewrote a table or vertex attribute), or was written by an older schema: ``str(e)``
    is ``"<path>: <what is stale> ...; likely broken by <tool>"`` on one line. Readers refuse such a
    file rather than draw wrong pixels."""
