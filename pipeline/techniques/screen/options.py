"""screen: its bake options (`BakeOptions`' ``screen_*`` fields, TOML keys and ``--screen-*`` flags) and
the per-material precompute's: no numpy here, so that ``sssbake bake --help`` imports none."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.techniques.option import option


@dataclass(frozen=True)
class ScreenSamplesOptions:
    """Attributes
    ----------
    samples : int
        N, importance-sampled offsets.
    uniform : int
        U, uniform offsets (0: importance samples alone).
    table_error : float
        Bound on the Rd table's relative interpolation error.
    seed : int
        Jitter of the strata and of the spiral's start.
    """

    samples: int = 32
    uniform: int = 8
    table_error: float = 1e-3
    seed: int = 0

    def check(self) -> None:
        if not (isinstance(self.samples, int) and 1 <= self.samples <= 4096):
            raise ValueError(f"screen: samples must be a whole number in [1, 4096], got {self.samples!r}")
        if not (isinstance(self.uniform, int) and 0 <= self.uniform <= 4096):
            raise ValueError(f"screen: uniform must be a whole number in [0, 4096], got {self.uniform!r}")
        if not (isinstance(self.table_error, (int, float)) and 1e-6 <= self.table_error <= 0.1):
            raise ValueError(f"screen: table_error must be in [1e-6, 0.1], got {self.table_error!r}")


SCREEN_DEFAULTS = ScreenSamplesOptions()
_D = SCREEN_DEFAULTS


@dataclass(frozen=True)
class ScreenOptions:
    """Attributes
    ----------
    samples, uniform, table_error
        The per-material precompute (`ScreenSamplesOptions`): importance-sampled and
        uniform offsets, bound on the Rd table's relative interpolation error.
    """

    samples: int = option(_D.samples, "screen: importance-sampled offsets per material (default {default:g})")
    uniform: int = option(_D.uniform, "screen: uniform offsets per material, 0 for none (default {default:g})")
    table_error: float = option(_D.table_error, "screen: bound on the Rd table's relative interpolation error "
                                                "(default {default:g})")

    def samples_options(self) -> ScreenSamplesOptions:
        return ScreenSamplesOptions(self.samples, self.uniform, self.table_error)

    def check(self) -> None:
        """Raise ValueError with a one-line reason for an impossible setting."""
        self.samples_options().check()
