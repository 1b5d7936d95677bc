"""The bending stiffness B(psi) of the two-phase membrane: the law and its derivatives; pure functions.

    linear:      B(psi) = B1 + (B2 - B1) psi                      (SPEC section 1, for every psi)
    saturating:  B(psi) = B1 + (B2 - B1) s(psi),  s(psi) = psi on [0, 1], and outside it

        s(1 + w x) = 1 + w G(x),   s(-w x) = -w G(x)   (x > 0, w = ``bending_width``),
        s'  = f(x) = erfc(a ln x) / 2,                              a = SHARPNESS = 2,
        G(x) = int_0^x f = x erfc(a ln x) / 2 + exp(1/(4 a^2)) erfc(1/(2a) - a ln x) / 2.

f fades from 1 to 0 as a log-normal tail: 1 - f ~ exp(-a^2 ln^2 x) vanishes
faster than any power of x as x -> 0, so s is C-infinity across psi = 0 and 1
(the spectral accuracy of the solver is kept), and B' is the linear law's to
1e-15 within 0.06 w of [0, 1] and to 4e-11 within 0.1 w (healthy interfaces
overshoot by up to 0.005); f = 0.975 at x = 1/2, 0.5 at x = 1, 0.025 at x = 2. Beyond, B tends to the constants
B2 + (B2 - B1) w C past the soft end and B1 - (B2 - B1) w C past the hard one,
C = exp(1/(4 a^2)) = 1.0645, which stay positive for w < min(B1, B2) / (|B2 - B1| C).

Why (SPEC section 2; docs/numerics.md "Bending law"): with the linear law the
local energy (a0/eps) g(psi) + B(psi) H^2 / 2 is unbounded below in psi at high
curvature (B vanishes at psi = B1 / (B1 - B2), 1.11 for B2 = 0.1), so a strongly
deflated vesicle (Delta = 2.3) draws the soft phase past 1 at a sharpening tip,
converged in N and dt. The saturating law is the same model wherever psi is in
[0, 1], the physical range, and bounded below by a positive stiffness outside
it, so the double well confines psi again.
"""
from __future__ import annotations

import numpy as np
from scipy.special import erfc

from hpcves.numerics.reductions import maximum, minimum

LAWS = ("linear", "saturating")

#: a in f(x) = erfc(a ln x) / 2: the fade of B' outside [0, 1] (module docstring)
SHARPNESS = 2.0
#: G(infinity) = exp(1 / (4 a^2)): how far s goes beyond [0, 1], in widths
SATURATION = float(np.exp(0.25 / SHARPNESS**2))


def _inside(psi) -> bool:
    return 0.0 <= minimum(psi) and maximum(psi) <= 1.0


def _outside(psi, width):
    """(log x, sign, inside): ln of the distance x > 0 outside [0, 1] in widths (-inf inside),
    sign +1 past 1 and -1 below 0, and the mask of the points inside."""
    psi = np.asarray(psi, dtype=float)
    inside = (psi >= 0.0) & (psi <= 1.0)
    above = psi > 1.0
    x = np.where(above, psi - 1.0, -psi) / width
    with np.errstate(divide="ignore"):
        log_x = np.log(np.where(inside, 0.0, x))
    return log_x, np.where(above, 1.0, -1.0), inside


def fraction(psi, law: str, width: float):
    """s(psi): B = B1 + (B2 - B1) s(psi)."""
    if law == "linear" or _inside(psi):
        return psi
    log_x, sign, inside = _outside(psi, width)
    a = SHARPNESS
    G = 0.5 * np.exp(log_x) * erfc(a * log_x) + 0.5 * SATURATION * erfc(0.5 / a - a * log_x)
    return np.where(inside, psi, np.where(sign > 0, 1.0, 0.0) + sign * width * G)


def fraction_prime(psi, law: str, width: float):
    """s'(psi): 1 on [0, 1] (the scalar 1.0 for the linear law or when every psi is inside)."""
    if law == "linear" or _inside(psi):
        return 1.0
    log_x, _, inside = _outside(psi, width)
    return np.where(inside, 1.0, 0.5 * erfc(SHARPNESS * log_x))


def fraction_second(psi, law: str, width: float):
    """s''(psi): 0 on [0, 1] (None for the linear law or when every psi is inside: nothing to add).

    d/dpsi f(x(psi)) = f'(x) dx/dpsi, f'(x) = -a exp(-a^2 ln^2 x) / (sqrt(pi) x), dx/dpsi = sign / w."""
    if law == "linear" or _inside(psi):
        return None
    log_x, sign, inside = _outside(psi, width)
    a = SHARPNESS
    with np.errstate(over="ignore", invalid="ignore"):
        slope = -a / np.sqrt(np.pi) * np.exp(-(a * log_x) ** 2 - log_x)
    return np.where(inside, 0.0, sign * slope / width)


def stiffness_bounds(B1: float, B2: float, law: str, width: float) -> tuple[float, float]:
    """(inf, sup) of B over all psi (the linear law: unbounded unless B1 = B2)."""
    if law == "linear":
        return (-np.inf, np.inf) if B1 != B2 else (B1, B1)
    ends = (B1 - (B2 - B1) * width * SATURATION, B2 + (B2 - B1) * width * SATURATION)
    return min(ends), max(ends)


def largest_width(B1: float, B2: float) -> float:
    """The saturating law keeps B > 0 for widths below this (inf for B1 = B2)."""
    return np.inf if B1 == B2 else min(B1, B2) / (abs(B2 - B1) * SATURATION)
