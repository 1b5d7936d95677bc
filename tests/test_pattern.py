import numpy as np

from hpcves.analysis.pattern import soft_domains


def test_soft_domains_are_counted_around_the_closed_membrane():
    alpha = np.arange(64) / 64
    assert soft_domains(0.5 + 0.4 * np.cos(2 * np.pi * alpha)) == [(49, 31)]        # one, through alpha = 0
    two = soft_domains(0.5 + 0.4 * np.cos(4 * np.pi * (alpha - 0.01)))              # one per tip
    assert two == [(25, 16), (57, 16)]                  # nodes 25-40, and 57-63 with 0-8 across alpha = 0
    assert soft_domains(np.full(64, 0.2)) == [] and soft_domains(np.full(64, 0.9)) == [(0, 64)]
    assert soft_domains(np.r_[np.ones(10), np.zeros(54)]) == [(0, 10)]
    assert soft_domains(np.r_[np.zeros(54), np.ones(10)]) == [(54, 10)]
    assert len(soft_domains(0.5 + 0.4 * np.cos(6 * np.pi * alpha + 0.1))) == 3


def test_the_topology_of_a_pattern():
    from hpcves.analysis.pattern import Topology, common_topology, tips, topology

    alpha = np.arange(64) / 64
    H = 3 + 2 * np.cos(4 * np.pi * alpha)                                 # tips at alpha = 0 and 1/2
    assert tips(H) == [0, 32]
    two = 0.5 + 0.4 * np.cos(4 * np.pi * (alpha - 0.01))                  # one domain per tip
    assert topology(two, H) == Topology(2, 2, True)
    assert topology(two, H).text() == "2 soft domains, both on tips, two-fold symmetric"
    one = 0.5 + 0.4 * np.cos(2 * np.pi * (alpha - 0.25))                  # one domain on a flank
    assert topology(one, H) == Topology(1, 0, False) and topology(one, H).text() == "1 soft domain"
    on_tip = 0.5 + 0.4 * np.cos(2 * np.pi * alpha)
    assert topology(on_tip, H).text() == "1 soft domain, on a tip"
    assert topology(np.full(64, 0.1), H).text() == "no soft domain"
    assert common_topology([two, two, one], [H, H, H]) == (Topology(2, 2, True), False)
    assert common_topology([], []) == (None, False)
