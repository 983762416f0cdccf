"""screen: its bake options (`BakeOptions`' ``screen_*`` fields, TOML keys and ``--screen-*`` flags)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.techniques.option import option
from sssbake.pipeline.techniques.screen.samples import SCREEN_DEFAULTS, ScreenSamplesOptions

_D = SCREEN_DEFAULTS


@dataclass(frozen=True)
class ScreenOptions:
    """Attributes
    ----------
    samples, uniform, table_error
        The per-material precompute (`samples.ScreenSamplesOptions`): importance-sampled and
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
