"""Regimes from a run's series (analysis/regimes.classify): tank-treading, phase-treading, tumbling,
undecided -- and the bending-energy gap and the settings -- on synthetic records with known answers."""
import numpy as np
import pytest

from hpcves.analysis.periodicity import analyze
from hpcves.analysis.regimes import PT, TT, TU, UNDECIDED, AnalysisSettings, classify
from hpcves.config import ConfigError
from hpcves.run.verdict import crept
from synthetic import SIGNALS, T, fold, oscillation, series, t


def test_tank_treading_phase_treading_and_tumbling_are_told_apart():
    tt = classify(series(0.56 - 0.3 * np.exp(-t / 1.2), pattern_speed=1e-6))
    assert tt.regime == TT and tt.theta_mean == pytest.approx(0.56, abs=1e-4), tt
    pt = classify(series(SIGNALS["noise 10 %"]))
    assert pt.regime == PT and pt.period == pytest.approx(T, rel=5e-3) and pt.theta_min > 0, pt
    assert pt.pattern_speed == pytest.approx(0.5)
    flips = fold(-np.arctan2(0.4 * np.sin(2 * np.pi * t / (2 * T)), np.cos(2 * np.pi * t / (2 * T))))
    tu = classify(series(flips))
    assert tu.regime == TU and tu.theta_min < 0 and tu.period == pytest.approx(T, rel=5e-3), tu
    assert tu.flips == pytest.approx(tu.cycles, abs=1) and "theta flips" in tu.reason, tu   # a turn by pi a period


def test_a_vesicle_that_swings_below_zero_without_flipping_is_told_from_a_tumbling_one():
    """Delta = 2.3, psi_bar = 0.5, S = 10 (issue 65): theta swings between -0.09 and 0.80 and never passes
    through -pi/2. min theta < 0 makes it TU by the publication's criterion; the classification says it
    swings (flips = 0), where a vesicle that turns over flips once a period (a turn by pi)."""
    swinging = classify(series(oscillation(t, mean=0.355, amplitude=0.25)))
    assert swinging.regime == TU and swinging.theta_min < 0 and swinging.flips == 0, swinging
    assert "swings below 0 without flipping" in swinging.reason and "Noguchi & Gompper" in swinging.reason
    assert swinging.period == pytest.approx(T, rel=5e-3)
    pt = classify(series(SIGNALS["clean"]))
    assert pt.regime == PT and np.isnan(pt.flips)


def test_a_mixture_that_never_separates_has_no_pattern_to_move():
    """psi_bar = 0.1 lies outside the spinodal: psi stays mixed (contrast ~0.03) and the
    'velocity' of its vanishing first mode is noise -- twice the membrane speed in one
    run at Delta = 0.94, S = 80. theta alone decides; a separated pattern still counts."""
    mixed = series(0.42 + 0.0 * t, pattern_speed=2.0)
    mixed["psi_min"], mixed["psi_max"] = np.full(t.size, 0.09), np.full(t.size, 0.12)
    c = classify(mixed)
    assert c.regime == TT and "psi stays mixed" in c.reason and np.isnan(c.pattern_speed)
    separated = dict(mixed, psi_min=np.full(t.size, -0.003), psi_max=np.full(t.size, 1.02))
    assert classify(separated).regime == UNDECIDED       # steady theta, moving pattern: as before


def test_homogeneous_vesicle_without_a_pattern_is_tank_treading():
    s = series(0.6 + 0.0 * t)
    s["V_psi"][:] = np.nan                           # psi = 0 everywhere: no phase position
    c = classify(s)
    assert c.regime == TT and "no phase pattern" in c.reason and np.isnan(c.pattern_speed)


@pytest.mark.parametrize("kind", ["NaN", "noise"])
def test_a_two_fold_symmetric_pattern_has_no_position_and_theta_decides(kind):
    """Delta = 2.3, psi_bar = 0.48: the soft phase sits at both tips, psi(alpha + 1/2) = psi(alpha) to
    1e-8, so the psi-weighted circular mean of alpha (the phase position) vanishes and V_psi is NaN
    (98 % of the samples at S = 4) or round-off noise (a spread of 25 tank-treading speeds at S = 28).
    Its few finite values made a "pattern speed" of 10 and 0.7: undecided, though theta and E_b were
    steady. With psi separated the pattern has no position and theta decides; a real PT stays PT."""
    rng = np.random.default_rng(1)
    s = series(0.3 + 0.0 * t)
    s["psi_min"], s["psi_max"] = np.full(t.size, 0.003), np.full(t.size, 1.02)
    if kind == "NaN":
        s["V_psi"] = np.where(rng.random(t.size) < 0.98, np.nan, rng.normal(0, 300.0, t.size))
    else:
        s["V_psi"] = rng.normal(0, 250.0, t.size)
    c = classify(s)
    assert c.regime == TT and "no position" in c.reason and "two-fold" in c.reason, c.reason
    pt = series(SIGNALS["noise 10 %"])
    pt["psi_min"], pt["psi_max"] = np.full(t.size, 0.003), np.full(t.size, 1.02)
    pt["V_psi"] = pt["V_psi"] + rng.normal(0, 5.0, t.size)          # a spread of 0.5 TT speeds: a measurement
    assert classify(pt).regime == PT


@pytest.mark.parametrize("case, words", [
    ("few samples", "too short"),
    ("two periods", "run longer"),
    ("steady only at the end", "not settled"),
    ("still drifting", "drifting"),
    ("pattern fixed but theta oscillates", "fixed in the lab frame"),
    ("pattern moves but theta steady", "theta steady"),
])
def test_undecided_rather_than_guessing(case, words):
    short = t[t < 1.4]
    signals = {
        "few samples": series(oscillation(t[:30]), time=t[:30]),
        "two periods": series(oscillation(short), time=short),
        "steady only at the end": series(0.56 - 0.3 * np.exp(-t / 4.0), pattern_speed=0.0),
        "still drifting": series(oscillation(t) + 0.05 * t),
        "pattern fixed but theta oscillates": series(oscillation(t), pattern_speed=1e-6),
        "pattern moves but theta steady": series(0.6 + 0.0 * t, pattern_speed=0.5),
    }
    c = classify(signals[case])
    assert c.regime == UNDECIDED and words in c.reason, (case, c)
    # only theta steady with the pattern moving is creep, which a refinement may run again more finely
    row = {"regime": c.regime, "reason": f"interrupted at t = 3 of 20: {c.reason}"}
    assert crept(row) == (case == "pattern moves but theta steady")


def test_a_decided_case_never_creeps():
    for theta, speed in ((0.56 - 0.3 * np.exp(-t / 1.2), 1e-6), (SIGNALS["noise 10 %"], 0.5)):
        c = classify(series(theta, pattern_speed=speed))
        assert c.regime in (TT, PT) and not crept({"regime": c.regime, "reason": c.reason})


def test_settings_are_checked():
    assert AnalysisSettings.from_dict({"min_cycles": 5}).min_cycles == 5.0
    with pytest.raises(ConfigError, match="unknown key mincycles"):
        AnalysisSettings.from_dict({"mincycles": 5})
    with pytest.raises(ConfigError, match="must be > 0"):
        AnalysisSettings(abs_tol=-1.0)
    with pytest.raises(ConfigError, match="must be a number"):
        AnalysisSettings(rel_tol="x")


def test_a_tumbling_period_of_whole_samples_is_not_locked_to_the_sample_grid():
    """The folded angle jumps at every flip between two samples; with a flip period of exactly 355
    sample intervals (the TU case psi_bar = 0.5, Delta = 0.94, S = 5 at h = 0.02 came close) its
    crossings all fall at the same place in a sample interval, and a period estimated from them
    carried an error 50x too small for how far it was off. The flip period comes from sin 2 theta."""
    h, true = 0.02, 355 * 0.02 + 0.0013               # 0.0013 off the sample grid
    time = np.arange(0.0, 60.0, h)
    phase = 2 * np.pi * time / true
    # a flip rate that varies along the cycle, and a 1e-3 alternation between successive flips
    angle = -(np.pi * time / true + 0.25 * np.sin(phase) + 1e-3 * np.sin(0.5 * phase))
    tu = classify(series(fold(angle), time=time))
    assert tu.regime == TU, tu
    assert abs(tu.period - true) <= max(tu.period_err, 1e-4), (tu.period, tu.period_err, true)
    assert tu.period_err < 2e-3


def test_the_bending_energy_gap_is_max_minus_min_over_a_period_and_its_error_covers_it():
    from hpcves.analysis.regimes import bending_gap

    gap_true, T = 0.37, 0.7
    energy = 5.0 + 0.5 * gap_true * np.sin(2 * np.pi * t / T) + 0.1 * gap_true * np.sin(4 * np.pi * t / T + 0.3)
    # the two-harmonic waveform's max - min, on a fine grid
    fine = np.linspace(0, T, 200001)
    exact = np.ptp(0.5 * gap_true * np.sin(2 * np.pi * fine / T) + 0.1 * gap_true * np.sin(4 * np.pi * fine / T + 0.3))
    gap, error = bending_gap(t, energy, T, t_settle=2.0)
    assert abs(gap - exact) <= error and error < 1e-3 * exact, (gap, exact, error)
    noise = np.random.default_rng(2026).standard_normal((5, t.size))[4]    # the draws it always had
    noisy = energy + 1e-3 * noise
    gap, error = bending_gap(t, noisy, T, t_settle=2.0)
    assert abs(gap - exact) <= error + 2e-3, (gap, exact, error)     # noise widens every period's range
    assert np.isnan(bending_gap(t, energy, T, t_settle=t[-1] - 0.5 * T)[0])   # no whole settled period
    pt = classify({**series(SIGNALS["noise 10 %"]), "E_bending": energy})
    assert pt.regime == PT and pt.bending_gap == pytest.approx(exact, rel=2e-3)
    tt = classify({**series(0.56 - 0.3 * np.exp(-t / 1.2), pattern_speed=1e-6), "E_bending": energy})
    assert tt.regime == TT and np.isnan(tt.bending_gap)


def test_a_tumbling_vesicle_whose_flips_jitter_is_decided_by_its_flips():
    """The authors' start at Delta = 2.3, S = 5 flips every 2.40-2.70 (its pattern modulates the flips):
    the fast flips fall between samples at varying places, theta's sampled extremes jitter by more
    than the settling band, and theta alone never settled. The flips settle once their intervals stop
    trending -- not during the slower flips of a start-up -- and the mean flip interval carries the
    spread of the intervals."""
    h, mean, k = 0.02, 2.55, np.arange(32)
    lengths = mean * (1 + 0.03 * np.sin(2 * np.pi * 0.382 * k))     # flips modulated quasi-periodically
    lengths += 0.4 * np.exp(-k / 2.0)                                 # after slower ones at the start
    ends = np.concatenate([[0.0], np.cumsum(lengths)])
    time = np.arange(0.0, ends[-1] - 1.0, h)
    cycle = np.searchsorted(ends, time, side="right") - 1
    x = np.pi * (cycle + (time - ends[cycle]) / lengths[cycle])
    theta = fold(-np.arctan2(0.05 * np.sin(x), np.cos(x)))         # a fast flip, slow elsewhere
    assert analyze(time, theta).cycles < 3                            # on theta: not settled
    tu = classify(series(theta, time=time))
    assert tu.regime == TU and "settled by its flips" in tu.reason, tu
    assert abs(tu.period - mean) <= tu.period_err < 0.01 * mean, (tu.period, tu.period_err)
    assert tu.t_settle >= ends[3] and tu.cycles >= 10, (tu.t_settle, tu.cycles)
    steady = classify(series(fold(-np.arctan2(0.05 * np.sin(np.pi * time / mean), np.cos(np.pi * time / mean))),
                             time=time))
    assert steady.regime == TU and "settled by its flips" not in steady.reason, steady   # theta settles
