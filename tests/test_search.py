"""The critical shear rate search on synthetic regime maps (no solver involved)."""
import math

import pytest

from hpcves.analysis.search import CONVERGED, RUNNING, STOPPED, UNBRACKETED, SearchSettings, estimate_critical, step
from hpcves.model.params import ConfigError


def run_search(settings, regime_at):
    """Drive a search to its end: every requested case 'runs' by looking up the map."""
    results = {}
    while True:
        state = step(settings, results)
        if state.status != RUNNING:
            return state, results
        assert state.next_values and not set(state.next_values) & set(results)
        for s in state.next_values:
            results[s] = regime_at(s)


def threshold(critical):
    return lambda s: "PT" if s >= critical else "TT"


@pytest.mark.parametrize("critical", [11.0, 37.3, 80.0, 151.7, 299.0])
@pytest.mark.parametrize("rel_tol", [0.1, 0.02, 0.005])
def test_the_search_brackets_the_transition_to_the_tolerance(critical, rel_tol):
    settings = SearchSettings(low=10.0, high=320.0, rel_tol=rel_tol, max_cases=40)
    state, results = run_search(settings, threshold(critical))
    assert state.status == CONVERGED, state
    assert state.low < critical <= state.high                     # the truth is inside the bracket
    assert state.high / state.low - 1 <= rel_tol
    assert abs(state.centre - critical) / critical <= rel_tol
    assert len(results) <= settings.cases_needed()                 # bisection: logarithmic cost


def test_a_range_without_a_transition_says_where_s_c_lies():
    settings = SearchSettings(low=10.0, high=320.0)
    above, _ = run_search(settings, threshold(1000.0))
    assert above.status == UNBRACKETED and "S_C > 320" in above.reason
    below, _ = run_search(settings, threshold(5.0))
    assert below.status == UNBRACKETED and "S_C < 10" in below.reason and below.high == 10.0


def test_undecided_or_reentrant_maps_stop_the_search_with_the_reason():
    settings = SearchSettings(low=10.0, high=320.0)
    undecided, _ = run_search(settings, lambda s: "undecided" if 40 < s < 100 else threshold(60.0)(s))
    assert undecided.status == STOPPED and "undecided" in undecided.reason
    reentrant = {10.0: "TT", 320.0: "PT", 56.5685424949: "PT", 23.7841423001: "TT", 36.6787800634: "TT"}
    state = step(settings, {**reentrant, 200.0: "TT"})
    assert state.status == STOPPED and "not a single transition" in state.reason


def test_max_cases_bounds_the_work():
    settings = SearchSettings(low=10.0, high=320.0, rel_tol=1e-6, max_cases=6)
    state, results = run_search(settings, threshold(77.0))
    assert state.status == STOPPED and len(results) == 6 and state.low < 77.0 <= state.high


def test_the_next_case_depends_only_on_the_results():
    settings = SearchSettings(low=10.0, high=320.0)
    a = step(settings, {320.0: "PT", 10.0: "TT"})
    b = step(settings, {10.0: "TT", 320.0: "PT"})
    assert a.next_values == b.next_values == (pytest.approx(math.sqrt(3200.0)),)
    assert (a.low, a.high, a.status) == (b.low, b.high, b.status) == (10.0, 320.0, RUNNING)


def test_bad_settings_are_refused():
    with pytest.raises(ConfigError, match="low < high"):
        SearchSettings(low=100.0, high=10.0)
    with pytest.raises(ConfigError, match="rel_tol"):
        SearchSettings(low=1.0, high=10.0, rel_tol=0.0)


@pytest.mark.parametrize("points", [2, 3, 7])
@pytest.mark.parametrize("critical", [11.0, 80.0, 299.0])
def test_k_section_converges_in_fewer_stages(points, critical):
    """points = k runs k shear rates per stage: the bracket shrinks by k + 1 per stage."""
    settings = SearchSettings(low=10.0, high=320.0, rel_tol=0.02, max_cases=80, points=points)
    results, stages = {}, 0
    while (state := step(settings, results)).status == RUNNING:
        assert len(state.next_values) == (points + 1 if stages == 0 else points)
        stages += 1
        for s in state.next_values:
            results[s] = threshold(critical)(s)
    assert state.status == CONVERGED and state.low < critical <= state.high
    assert state.high / state.low - 1 <= 0.02
    assert len(results) <= settings.cases_needed() and stages <= settings.stages_needed()
    assert stages < SearchSettings(low=10.0, high=320.0, rel_tol=0.02).stages_needed()


def test_search_settings_from_a_table():
    s = SearchSettings.from_dict({"low": 10, "high": 320, "points": 2})
    assert (s.low, s.high, s.points, s.rel_tol) == (10.0, 320.0, 2, 0.02)
    with pytest.raises(ConfigError, match="unknown key tolerance"):
        SearchSettings.from_dict({"low": 10, "high": 320, "tolerance": 0.1})
    with pytest.raises(ConfigError, match="give high"):
        SearchSettings.from_dict({"low": 10})
    with pytest.raises(ConfigError, match="search.points"):
        SearchSettings.from_dict({"low": 10, "high": 320, "points": 1.5})


def test_a_search_along_lambda_speaks_of_lambda_c():
    """[search] along = "viscosity_ratio": the same bisection, TT below lambda_C and TU above."""
    settings = SearchSettings.from_dict({"low": 1, "high": 20, "along": "viscosity_ratio", "rel_tol": 0.05})
    assert (settings.symbol, settings.column, settings.stem) == ("lambda", "lambda_C", "critical_lambda")
    state, results = run_search(settings, lambda lam: "TU" if lam >= 4.2 else "TT")
    assert state.status == CONVERGED and state.low < 4.2 <= state.high and "lambda_C in [" in state.reason
    above, _ = run_search(settings, lambda lam: "TT")
    assert "TT up to lambda = 20: lambda_C > 20" in above.reason
    assert SearchSettings(low=10.0, high=320.0).column == "S_C"
    with pytest.raises(ConfigError, match="search.along = 'psi_bar'"):
        SearchSettings.from_dict({"low": 1, "high": 20, "along": "psi_bar"})
    with pytest.raises(ConfigError, match="the range of lambda"):
        SearchSettings.from_dict({"low": 1, "along": "viscosity_ratio"})


# --- the best estimate inside a bracket (estimate_critical)
def saddle_node(critical, curvature=0.0, upper="TU"):
    """A saddle-node on a circle at ``critical``: above it a periodic motion with 1/T^2 = 0.3 d exp(c d),
    d = x - critical; below it a stationary state with theta^2 = 0.05 d exp(c d), d = critical - x."""
    def at(x):
        d = abs(x - critical)
        if x >= critical:
            frequency2 = 0.3 * d * math.exp(curvature * d)
            return (upper, math.nan, 1 / math.sqrt(frequency2) if frequency2 > 0 else math.inf)
        return ("TT", math.sqrt(0.05 * d * math.exp(curvature * d)), math.nan)
    return at


def searched(critical, curvature=0.0, upper="TU", rel_tol=0.05):
    settings = SearchSettings(low=2.0, high=8.0, rel_tol=rel_tol, along="viscosity_ratio", max_cases=40)
    motion = saddle_node(critical, curvature, upper)
    state, results = run_search(settings, lambda x: motion(x)[0])
    assert state.status == CONVERGED
    return state, {x: motion(x) for x in results}


def test_the_estimate_of_an_exact_saddle_node_is_its_critical_value():
    state, cases = searched(4.23)
    estimate = estimate_critical(state.low, state.high, cases)
    assert estimate.value == pytest.approx(4.23, abs=1e-9)
    assert len(estimate.extrapolations) == 2 and "weighted mean of" in estimate.method     # both sides used


@pytest.mark.parametrize("curvature, share", [(-0.2, 0.1), (0.3, 0.2), (1.0, 0.3)])
@pytest.mark.parametrize("critical", [2.31, 3.05, 4.15, 4.23, 5.5, 6.74, 7.4])
def test_the_estimate_lies_inside_the_bracket_and_nearer_the_truth_than_the_centre(critical, curvature, share):
    state, cases = searched(critical, curvature)
    estimate = estimate_critical(state.low, state.high, cases)
    assert state.low <= estimate.value <= state.high
    # the scaling's next order (exp(c d): 1/T^2 bends by about c d over the cases' distance d) leaves an error
    # that grows with c: a ``share`` of the bracket, and less than the centre's wherever that is larger
    width = state.high - state.low
    assert abs(estimate.value - critical) <= share * width
    if abs(state.centre - critical) > share * width:
        assert abs(estimate.value - critical) < abs(state.centre - critical)


def test_the_estimate_narrows_with_the_bracket():
    errors = []
    for rel_tol in (0.1, 0.02, 0.005):
        state, cases = searched(4.23, curvature=1.0, rel_tol=rel_tol)
        errors.append(abs(estimate_critical(state.low, state.high, cases).value - 4.23))
    assert errors[0] > errors[1] > errors[2]


def test_a_phase_treading_transition_uses_the_period_alone():
    state, cases = searched(4.23, upper="PT")
    estimate = estimate_critical(state.low, state.high, cases)
    assert len(estimate.extrapolations) == 1 and estimate.method.startswith("1/T^2 -> 0 above (PT)")
    assert estimate.value == pytest.approx(4.23, abs=1e-9)


def test_an_extrapolation_outside_the_bracket_is_named_and_not_used():
    # periods that do not diverge at the bracket (a finite-frequency onset): 1/T^2 -> 0 lies far below it
    cases = {4.0: ("TT", 0.1, math.nan), 4.2: ("TT", 0.0, math.nan), 4.3: ("PT", math.nan, 2.0),
             4.5: ("PT", math.nan, 1.9)}
    estimate = estimate_critical(4.2, 4.3, cases)
    assert math.isnan(estimate.value)
    assert "no extrapolation inside the bracket" in estimate.method and "1/T^2 -> 0 above (PT) gives" in estimate.method
    # a frequency that falls away from the transition gives nothing to extrapolate
    falling = {**cases, 4.5: ("PT", math.nan, 2.5)}
    assert estimate_critical(4.2, 4.3, falling).extrapolations == ()


def test_only_cases_near_the_bracket_are_extrapolated_from():
    """A search's first stage leaves a case at the range's end; T ~ 1/S there, not (S - S_C)^(-1/2): a
    secant through it would pin the root to the bracket's end."""
    cases = {35.0: ("TT", 0.57, math.nan), 38.7: ("TT", 0.57, math.nan), 40.0: ("PT", 0.58, 0.65),
             320.0: ("PT", 0.59, 0.0217)}
    estimate = estimate_critical(38.7, 40.0, cases)
    assert math.isnan(estimate.value) and "no two cases on a side within 5 bracket widths" in estimate.method
    near = {**cases, 44.0: ("PT", 0.58, 0.3)}                            # within 5 widths (6.5) of 40
    assert 38.7 <= estimate_critical(38.7, 40.0, near).value <= 40.0
