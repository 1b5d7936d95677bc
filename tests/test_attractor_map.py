import math

from hpcves.reports import attractor_map


def _row(S, psi_bar, regime, domains, theta=0.3, period=math.nan, N=128):
    return {"shear_rate": S, "psi_bar": psi_bar, "excess_length": 2.3, "B2": 0.1, "regime": regime, "N": N,
            "theta_mean": theta, "theta_mean_err": 1e-4, "theta_mean_dt_err": math.nan, "period": period,
            "period_err": 1e-4 if math.isfinite(period) else math.nan, "period_dt_err": math.nan,
            "soft_domains": float(domains), "domains_on_tips": float(min(domains, 2)), "two_fold": float(domains == 2),
            "topology_steady": 1.0}


def test_two_starts_compared_point_by_point(tmp_path):
    ellipse = [_row(28, 0.48, "TT", 2), _row(80, 0.48, "TT", 2), _row(5, 0.25, "TT", 2),
               _row(1, 0.5, "failed", 0, N=128), _row(1, 0.5, "TU", 1, theta=0.1, period=10.8, N=256)]
    smoothed = [_row(28, 0.48, "PT", 1, theta=0.26, period=0.638), _row(80, 0.48, "TT", 2),
                _row(1, 0.5, "TU", 1, theta=0.1, period=10.8), _row(350, 0.75, "TT", 2)]
    compared = attractor_map.compare({"ellipse": ellipse, "smoothed": smoothed})
    by_point = {(c["shear_rate"], c["psi_bar"]): c for c in compared}
    assert len(by_point[(28, 0.48)]["attractors"]) == 2 and len(by_point[(80, 0.48)]["attractors"]) == 1
    assert [a.starts for a in by_point[(1, 0.5)]["attractors"]] == [("ellipse", "smoothed")]   # the N = 256 rerun
    assert set(by_point[(350, 0.75)]["rows"]) == {"smoothed"}
    text = attractor_map.summary(compared, ("ellipse", "smoothed"))
    assert text.startswith("3 points run from ellipse and smoothed (2 more from one of them only).")
    assert "| TT / PT | 2 different | 1 |" in text and "| TT / TT | the same | 1 |" in text
    assert "| TU / TU | the same | 1 |" in text
    fig = attractor_map.figure(compared, ("ellipse", "smoothed"), "shear_rate", "psi_bar", "Delta = 2.3")
    fig.savefig(tmp_path / "map.png")
    assert (tmp_path / "map.png").stat().st_size > 10000


def test_tumbling_periods_compare_within_the_orbit_spread():
    a = _row(4, 0.48, "TU", 1, theta=0.13, period=4.7259)
    near, far = dict(a, period=4.7385, theta_mean=0.16), dict(a, period=4.9)     # 0.27 % and 3.7 % apart
    assert len(attractor_map.compare({"a": [a], "b": [near]})[0]["attractors"]) == 1
    assert len(attractor_map.compare({"a": [a], "b": [far]})[0]["attractors"]) == 2


def test_starts_at_slightly_different_parameters_compare_by_regime_and_topology():
    a, b = _row(80, 0.5, "PT", 1, theta=0.59, period=0.0862), _row(80, 0.5, "PT", 1, theta=0.60, period=0.0870)
    assert len(attractor_map.compare({"a": [a], "b": [b]})[0]["attractors"]) == 2
    assert len(attractor_map.compare({"a": [a], "b": [b]}, values=False)[0]["attractors"]) == 1
    c = _row(80, 0.5, "PT", 2, theta=0.60, period=0.0870)
    assert len(attractor_map.compare({"a": [a], "c": [c]}, values=False)[0]["attractors"]) == 2
