"""toy: its bake options (``toy_gain``, ``--toy-gain``)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.techniques.option import option


@dataclass(frozen=True)
class ToyOptions:
    """Attributes
    ----------
    gain
        Scale of the albedo R_d.
    """

    gain: float = option(1.0, "toy: scale of the albedo R_d (default {default:g})")

    def check(self) -> None:
        if not 0.0 < self.gain <= 10.0:
            raise ValueError(f"toy_gain must be in (0, 10], got {self.gain!r}")
