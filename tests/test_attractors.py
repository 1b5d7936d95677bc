import math

from hpcves.analysis.attractors import Run, group, same_attractor
from hpcves.analysis.pattern import Topology

TWO = Topology(2, 2, True)
ONE = Topology(1, 0, False)


def test_runs_group_into_the_attractors_they_reached():
    runs = [Run("ellipse", "TT", TWO, 0.2979, 1e-4),
            Run("smoothed", "PT", ONE, 0.2618, 2e-4, 0.63792, 2e-4),
            Run("one domain", "PT", ONE, 0.2615, 2e-4, 0.63772, 2e-4),
            Run("random 1", "TT", TWO, 0.29795, 1e-4),
            Run("random 2", "undecided", None, math.nan, math.nan),
            Run("random 3", "PT", ONE, 0.2618, 2e-4, 0.70, 2e-4)]          # another period: another orbit
    found = group(runs)
    assert [a.starts for a in found] == [("ellipse", "random 1"), ("smoothed", "one domain"), ("random 3",)]
    assert found[0].text() == ("TT, 2 soft domains, both on tips, two-fold symmetric, theta 0.2979: "
                               "from ellipse, random 1")
    assert found[1].text().startswith("PT, 1 soft domain, period 0.63792")


def test_same_regime_is_not_enough():
    a = Run("a", "TT", TWO, 0.30, 1e-3)
    assert not same_attractor(a, Run("b", "TT", ONE, 0.30, 1e-3))          # another topology
    assert not same_attractor(a, Run("b", "TT", TWO, 0.31, 1e-3))          # theta apart by more than the bars
    assert same_attractor(a, Run("b", "TT", TWO, 0.3015, 1e-3))
    assert not same_attractor(a, Run("b", "PT", TWO, 0.30, 1e-3, 0.5, 1e-3))
    assert same_attractor(Run("a", "TT", None, 0.3, math.nan), Run("b", "TT", None, 0.3, math.nan))
