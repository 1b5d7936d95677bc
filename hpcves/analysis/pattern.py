"""The topology of a phase pattern on the closed membrane: its soft domains.

A soft domain is a maximal arc of material points where psi > 1/2 (the midpoint
of the double well g = psi^2 (1 - psi)^2 / 4, whose minima are the phases psi = 0
and 1), counted periodically in alpha. A uniform pattern on either side of 1/2
has no domain or one covering everything. The topology of a pattern
(:class:`Topology`) adds where the domains sit -- on the tips, the two highest
curvature peaks, or not -- and whether the pattern is two-fold symmetric; in
the deflated regime it tells coexisting states apart that share a regime.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hpcves.numerics.runs import periodic_runs

#: the value of psi between the hard (0) and the soft (1) phase that separates them
INTERFACE = 0.5


def soft_domains(psi: np.ndarray, interface: float = INTERFACE) -> list[tuple[int, int]]:
    """The soft domains of ``psi`` (values at equispaced material points, periodic) as
    (first node, node count) pairs in the order of alpha; a domain through alpha = 0 starts
    before it (its first node is the one after the last hard node)."""
    return periodic_runs(np.asarray(psi) > interface)


#: a pattern is two-fold symmetric where psi(alpha + 1/2) and psi(alpha) differ by less than this
TWO_FOLD_TOLERANCE = 0.1


@dataclass(frozen=True)
class Topology:
    """What a phase pattern is, beyond its regime: how many soft domains, how many of them hold one of
    the membrane's two tips (its two highest curvature peaks), and whether it is two-fold symmetric
    (psi(alpha + 1/2) = psi(alpha): the same on both halves, one domain per tip or none)."""

    domains: int
    on_tips: int
    two_fold: bool

    def text(self) -> str:
        if self.domains == 0:
            return "no soft domain"
        count = f"{self.domains} soft domain{'s' * (self.domains > 1)}"
        tips = ("" if self.on_tips == 0 else ", on a tip" if self.domains == self.on_tips == 1 else
                ", both on tips" if self.domains == self.on_tips == 2 else f", {self.on_tips} on tips")
        return count + tips + (", two-fold symmetric" if self.two_fold else "")


def tips(curvature: np.ndarray) -> list[int]:
    """The nodes of the two highest local maxima of the curvature (periodic): the tips of the shape."""
    H = np.asarray(curvature)
    peaks = np.flatnonzero((H > np.roll(H, 1)) & (H >= np.roll(H, -1)))
    return sorted(int(i) for i in peaks[np.argsort(H[peaks])[::-1][:2]])


def topology(psi: np.ndarray, curvature: np.ndarray) -> Topology:
    """The :class:`Topology` of one snapshot (psi and the curvature H at the same material points)."""
    psi = np.asarray(psi)
    n = psi.size
    found = soft_domains(psi)
    tip_nodes = tips(curvature)
    on_tips = sum(any((node - first) % n < count for node in tip_nodes) for first, count in found)
    two_fold = n % 2 == 0 and float(np.max(np.abs(psi - np.roll(psi, n // 2)))) < TWO_FOLD_TOLERANCE
    return Topology(len(found), on_tips, two_fold)


def common_topology(psis, curvatures) -> tuple[Topology | None, bool]:
    """The topology most snapshots have, and whether all have it ((None, False) without snapshots)."""
    found = [topology(psi, H) for psi, H in zip(psis, curvatures)]
    if not found:
        return None, False
    counts = {t: found.count(t) for t in found}
    most = max(counts, key=lambda t: (counts[t], -found.index(t)))
    return most, counts[most] == len(found)
