"""Checks the exporters run before writing a value: no output may hold NaN or Inf."""

from __future__ import annotations

import math

import numpy as np


def check_finite(values: np.ndarray, what: str) -> None:
    """Raise ValueError naming `what` when `values` holds NaN or Inf."""
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what} has non-finite values (NaN or Inf)")


def finite_number(value, what: str) -> float:
    """`value` as a float; ValueError naming `what` when it is NaN or Inf."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{what} is not finite: {value}")
    return value
