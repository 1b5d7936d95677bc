"""The topology of a phase pattern on the closed membrane: its soft domains.

A soft domain is a maximal arc of material points where psi > 1/2 (the midpoint
of the double well g = psi^2 (1 - psi)^2 / 4, whose minima are the phases psi = 0
and 1), counted periodically in alpha. A uniform pattern on either side of 1/2
has none or one domain covering everything; both are reported as what they are
(0 soft domains, or 1 with ``covered`` the whole membrane).
"""
from __future__ import annotations

import numpy as np

#: the value of psi between the hard (0) and the soft (1) phase that separates them
INTERFACE = 0.5


def soft_domains(psi: np.ndarray, interface: float = INTERFACE) -> list[tuple[int, int]]:
    """The soft domains of ``psi`` (values at equispaced material points, periodic) as
    (first node, node count) pairs in the order of alpha; a domain through alpha = 0 starts
    before it (its first node is the one after the last hard node)."""
    soft = np.asarray(psi) > interface
    n = soft.size
    if soft.all():
        return [(0, n)]
    if not soft.any():
        return []
    start = int(np.argmin(soft))                       # a hard node: domains do not wrap past it
    rolled = np.roll(soft, -start)
    edges = np.diff(np.r_[0, rolled.astype(np.int8), 0])
    firsts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return sorted(((int(f) + start) % n, int(e - f)) for f, e in zip(firsts, ends))
