"""The range a physical input (a material coefficient, a scale, a length, a limit) may take for the
bake's arithmetic to stay finite, with why: read by the checks (`options.check_options`,
`materials.Material`), the CLI's help and the docs, so that all three give the same bounds."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: The longest length in mm the bake works with: the diffusion profile's radius search
#: (`profile.radius_for_energy`) stops here, so a length option past it means nothing more.
LENGTH_MAX_MM = 1e12


@dataclass(frozen=True)
class Range:
    """A closed or half-open interval of numbers, in a unit, with the reason for its ends.

    Attributes
    ----------
    low, high : float
        The ends.
    why : str
        Where the computation breaks past them (one sentence; the docs and the option's docs cite it).
    unit : str
        Appended to the interval in messages (e.g. ``"mm per file unit"``); empty for none.
    low_open, high_open : bool
        The end itself is excluded.
    says : str
        What a refusal says the value must be, where the interval alone reads badly (``"a finite
        number below 1"`` for (-1.8e308, 1)); empty: ``in <interval>``.
    """

    low: float
    high: float
    why: str
    unit: str = ""
    low_open: bool = False
    high_open: bool = False
    says: str = ""

    def __contains__(self, value) -> bool:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        # NaN compares false with both ends; an int too large for a float is past any end
        number = float(value) if abs(value) < 1e308 else math.inf if value > 0 else -math.inf
        above = number > self.low if self.low_open else number >= self.low
        below = number < self.high if self.high_open else number <= self.high
        return above and below

    def text(self) -> str:
        """The interval as ``[1e-06, 1e+06] mm per file unit``."""
        return (f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
                f"{' ' + self.unit if self.unit else ''}")

    def check(self, name: str, value) -> None:
        """Raise ValueError naming `name` and the interval unless `value` lies in it."""
        if value not in self:
            raise ValueError(f"{name} must be {self.says or 'in ' + self.text()}, got {shown(value)}")


#: Millimetres per file unit (`scale.resolve_scale_mm`), a nanometre to a kilometre. What breaks is
#: the object's size in mm: the 20-unit sample sphere bakes finite with every technique from 1e-9 to
#: 1e12 mm per unit (below, a render's float32 image overflows by 1e-12 and the escape walk loses all
#: light by 1e-20; above, embree's float32 coordinates overflow by 1e40), so the ends hold for
#: objects from 0.1 to 1e5 units across.
SCALE_MM = Range(1e-6, 1e6, "a 20-unit object bakes finite from 1e-9 to 1e12", "mm per file unit")


def shown(value, limit: int = 60) -> str:
    """``repr(value)`` cut to `limit` characters: a refused value is quoted in a one-line message,
    and a config may hold a 10,000-digit number or a 1 MB string."""
    try:
        text = repr(value)
    except ValueError:  # an int past Python's 4300-digit str limit
        return f"a {value.bit_length()}-bit whole number"
    return text if len(text) <= limit else text[:limit - 3] + "..."
