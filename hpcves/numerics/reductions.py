"""Extremes of short arrays without the cost of a ufunc reduction.

At N ~ 100, ``x.max()`` costs about 1 us, nearly all of it fixed overhead of
numpy's reduction machinery; ``x[x.argmax()]`` costs 0.3 us and is the same
value, NaN included (argmax points at the first NaN, as max propagates it).
The time step takes several such extremes (tolerances, plausibility checks).
"""
from __future__ import annotations

import numpy as np


def maximum(x: np.ndarray):
    """max(x)."""
    return x[x.argmax()]


def minimum(x: np.ndarray):
    """min(x)."""
    return x[x.argmin()]


def largest_magnitude(x: np.ndarray):
    """max |x|."""
    magnitude = np.abs(x)
    return magnitude[magnitude.argmax()]
