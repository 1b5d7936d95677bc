"""A start from another state: a stored shape and phase carried over to new parameters.

A continuation (a chain of cases along S or Delta, or a case started from the
stored state of another) starts from the tangent angle theta_tilde and the phase
psi of a state of another case -- possibly another N, excess length and mean
composition. :func:`carried_start` makes them a start of this case:

* both fields are resampled to N nodes by Fourier interpolation (they are
  periodic in alpha, and the nodes are equally spaced in arclength);
* the shape keeps its orientation and the form of its tangent angle; only the
  size of the angle's excess is changed, theta_tilde -> m + c (theta_tilde - m)
  with m its mean, by the c that gives the area of the new excess length
  Delta = L / sqrt(A / pi) - 2 pi at the same perimeter L (c = 1 when Delta is
  unchanged). This is the rule of the authors' smoothed start (geometry.py),
  applied to any shape;
* psi keeps its pattern and is shifted to the new mean psi_bar (its mean is a
  conserved quantity, so it must be set, not inherited).
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from hpcves.model import geometry
from hpcves.model.params import ConfigError, Physics
from hpcves.numerics.spectral import Spectral, resample

#: an area within this relative distance of the target is kept as it is (no rescaling)
AREA_KEPT = 1e-12


def target_area(length: float, excess_length: float) -> float:
    """A of the curve of perimeter L and excess length Delta: pi (L / (2 pi + Delta))^2."""
    return np.pi * (length / (2.0 * np.pi + excess_length)) ** 2


def carried_start(theta_tilde: np.ndarray, psi: np.ndarray, physics: Physics, sp: Spectral,
                  keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(theta_tilde, psi) at the N nodes of ``sp`` for a case of ``physics``, from another state's fields
    (any number of nodes): the shape rescaled to physics.excess_length, psi shifted to physics.psi_bar;
    ``keep``: a 0/1 mask of the Fourier modes of theta_tilde kept (Spectral.project)."""
    theta_tilde = resample(theta_tilde, sp.N)
    if keep is not None:
        theta_tilde = sp.project(theta_tilde, keep)
    psi = resample(psi, sp.N)
    if not (np.all(np.isfinite(theta_tilde)) and np.all(np.isfinite(psi))):
        raise ConfigError("the stored state to start from is not finite")
    theta_tilde = _with_area(theta_tilde, sp, target_area(sp.length, physics.excess_length),
                             physics.excess_length)
    if physics.homogeneous:
        psi = np.full(sp.N, physics.psi_bar)
    else:
        psi = psi - psi.mean() + physics.psi_bar
    return theta_tilde, psi


def _with_area(theta_tilde: np.ndarray, sp: Spectral, area: float, excess_length: float) -> np.ndarray:
    """theta_tilde with its excess scaled about its mean so that the closed curve encloses ``area``."""
    mean = theta_tilde.mean()
    excess = theta_tilde - mean

    def shaped(c):
        return geometry.close_curve(sp.circle_angle + mean + c * excess) - sp.circle_angle

    def area_over(c):
        return (geometry.enclosed_area(shaped(c) + sp.circle_angle, sp) - area) / area

    if abs(area_over(1.0)) <= AREA_KEPT:
        return shaped(1.0)
    if np.max(np.abs(excess)) == 0.0:
        raise ConfigError(f"the stored state is a circle: no shape of excess length {excess_length:g} "
                          "has its form")
    if area_over(1.0) > 0:                 # too round: more of its excess
        low, high = 1.0, 1.25
        while area_over(high) > 0:
            low, high = high, 1.25 * high
            if high > 64.0:
                raise ConfigError(f"the stored shape cannot be stretched to excess length {excess_length:g} "
                                  "by scaling its tangent angle")
    else:                                  # too deflated: less of it (c -> 0 is the circle)
        low, high = 0.0, 1.0
    c = optimize.brentq(area_over, low, high, xtol=1e-15, rtol=1e-15, maxiter=200)
    return shaped(c)
