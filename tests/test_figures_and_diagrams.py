"""Figures: what they show, read back from the matplotlib objects (not from pixels)."""
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from hpcves.analysis.regimes import OUTCOMES  # noqa: E402
from hpcves.reports import case_figures, diagrams  # noqa: E402


def _row(regime, S, psi_bar, period=math.nan):
    return {"regime": regime, "shear_rate": S, "psi_bar": psi_bar, "period": period}


def test_every_outcome_has_its_own_marker_and_legend_entry():
    rows = [_row(regime, S, 0.1 * k) for k, regime in enumerate(OUTCOMES, 1) for S in (5.0, 20.0)]
    fig = diagrams.phase_diagram(rows, "shear_rate", "psi_bar")
    try:
        legend = fig.axes[0].get_legend()
        labels = [t.get_text() for t in legend.get_texts()]
        assert len(labels) == len(OUTCOMES) and all(label.endswith("(2)") for label in labels)
        assert any(label.startswith("model limit") for label in labels)
        assert "failed (2)" in labels and "undecided (2)" in labels
        styles = {(str(diagrams.REGIME_STYLE[r][0]), diagrams.REGIME_STYLE[r][1]) for r in OUTCOMES}
        assert len(styles) == len(OUTCOMES)                 # no two outcomes look alike
        for collection, regime in zip(fig.axes[0].collections, OUTCOMES):
            assert np.allclose(collection.get_offsets()[:, 1], rows[2 * OUTCOMES.index(regime)]["psi_bar"])
    finally:
        plt.close(fig)


def test_a_kymograph_warns_when_its_snapshots_alias_the_fastest_period():
    # a material point goes round L = 2.64 at |V| = 1.32 in 2, its two tips pass in 1
    assert case_figures.fastest_period([-1.32, -1.32], 2.64) == 1.0
    assert case_figures.fastest_period([-1.32], 2.64, period=0.4) == 0.4           # the oscillation is faster
    assert math.isnan(case_figures.fastest_period([0.0], 2.64))
    assert case_figures.cadence_warning(1.0 / 8, 1.0) == ""
    coarse = case_figures.cadence_warning(0.25, 1.0)
    assert coarse.startswith("coarse: snapshots every 0.25, 4 per period 1") and "<= 0.12" in coarse
    assert case_figures.cadence_warning(0.6, 1.0).startswith("aliased")
    assert case_figures.cadence_warning(0.6, math.nan) == ""


def test_the_settled_window_and_the_shapes_of_the_last_period():
    t = np.linspace(0.0, 10.0, 1001)
    assert case_figures.settled_window(t, 4.0).sum() == 601
    assert case_figures.settled_window(t, math.nan).all()
    assert case_figures.settled_window(t, 9.995).all()                     # too few left
    snap_t = np.arange(0.0, 10.01, 0.25)
    last_period = case_figures._shape_indices(snap_t, 4.0, period=2.0, n_shapes=8)
    assert snap_t[last_period].min() >= 8.0 and last_period.size == 8 and snap_t[last_period[-1]] == 10.0
    spread = case_figures._shape_indices(snap_t, 4.0, period=math.nan, n_shapes=5)
    assert np.allclose(snap_t[spread], [4.0, 5.5, 7.0, 8.5, 10.0])


def _ellipse_snapshots(n_snapshots=6, N=64):
    """Snapshots of a still ellipse with zero force: the flow is the imposed shear."""
    alpha = np.arange(N) / N
    z = 0.5 * np.cos(2 * np.pi * alpha) + 0.3j * np.sin(2 * np.pi * alpha)
    zeros = np.zeros((n_snapshots, N))
    return {"t": np.arange(n_snapshots) * 0.5, "x": np.tile(z.real, (n_snapshots, 1)),
            "y": np.tile(z.imag, (n_snapshots, 1)), "psi": zeros + 0.5, "tension": zeros,
            "curvature": zeros, "velocity_x": np.tile(2.0 * z.imag, (n_snapshots, 1)),
            "velocity_y": zeros.copy(), "shift": np.zeros(n_snapshots)}


def test_a_case_page_shows_the_settled_window_streamlines_and_short_titles():
    from hpcves.model.params import Physics

    t = np.linspace(0.0, 3.0, 301)
    theta = 0.5 + 0.4 * np.exp(-10 * t) + 1e-4 * np.sin(2 * np.pi * t / 0.7)
    series = {"t": t, "theta": theta, "E_bending": 4.47 + 1e-5 * np.sin(t), "E_phase": 23.6 + np.exp(-t),
              "tension_min": t * 0, "tension_mean": t * 0 + 1, "tension_max": t * 0 + 2, "V_psi": t * 0 + 0.9,
              "V_L": t * 0 - 0.9, "tank_treading_velocity": t * 0 - 1.0}
    physics = Physics(shear_rate=2.0, B1=1.0, B2=1.0)     # f = 0 in these snapshots: u = S y, a uniform shear
    fig = case_figures.case_figure(series, _ellipse_snapshots(), title="case 0000: S = 2 -- PT", kymographs=True,
                                   t_settle=1.0, period=0.7, physics=physics, subtitle="stopped when decided")
    try:
        theta_ax = fig.axes[0]
        line = theta_ax.get_lines()[0]
        assert line.get_xdata()[0] == pytest.approx(1.0) and "settled from t = 1" in theta_ax.get_xlabel()
        assert np.ptp(line.get_ydata()) < 3e-4                       # the oscillation, not the transient
        assert theta_ax.get_ylabel().startswith(r"inclination $\theta$ $-$ 0.49999")   # about its mean
        assert fig._suptitle.get_text() == "case 0000: S = 2 -- PT\nstopped when decided"
        strip = next(ax for ax in fig.axes if ax.get_title().startswith("streamlines"))
        assert len(strip.collections) > 6                             # streamlines and shapes
        warnings = [ax.get_title() for ax in fig.axes if ax.get_title().startswith(("coarse", "aliased"))]
        assert len(warnings) == 2 and "per period 0.7" in warnings[0]
    finally:
        plt.close(fig)


def test_the_velocity_panel_leaves_a_few_spikes_off_its_scale_and_says_so():
    t = np.linspace(0.0, 4.0, 400)
    smooth = np.sin(2 * np.pi * t)
    fig, ax = plt.subplots()
    try:
        ax.plot(t, smooth)
        before = ax.get_ylim()
        assert case_figures._clip_outliers(ax, smooth) == ""            # a smooth oscillation keeps its extremes
        assert ax.get_ylim() == before
        spiky = 0.01 * smooth
        spiky[57] = -4300.0                                       # one sample of an undefined pattern position
        ax.plot(t, spiky)
        note = case_figures._clip_outliers(ax, spiky)
        assert note.startswith("1 of 400 values off the scale") and "-4.3e+03" in note
        low, high = ax.get_ylim()
        assert -0.05 < low < -0.01 and 0.01 < high < 0.05          # the oscillation fills the panel
    finally:
        plt.close(fig)


def test_a_region_is_drawn_only_where_the_cases_around_it_agree():
    """The demo's 3 x 2 grid (TT at S = 10, 40 and psi_bar = 0.3, PT elsewhere) was shaded by the nearest
    case: a TT rectangle ending at S = 60, psi_bar = 0.4, where no case was. Now a rectangle is filled
    only where its four corner cases share a regime; a search's rows fill the stretches both share."""
    from hpcves.analysis.regions import row_intervals, row_regions

    demo = [_row(regime, S, psi) for S, psi, regime in ((10, 0.3, "TT"), (40, 0.3, "TT"), (80, 0.3, "PT"),
                                                         (10, 0.5, "PT"), (40, 0.5, "PT"), (80, 0.5, "PT"))]
    assert diagrams.decided_regions(demo, "shear_rate", "psi_bar") == []
    grid = demo + [_row(regime, S, 0.1) for S, regime in ((10, "TT"), (40, "TT"), (80, "undecided"))]
    assert diagrams.decided_regions(grid, "shear_rate", "psi_bar") == [((10, 40, 0.1, 0.3), "TT")]
    # a point run twice with different regimes (two starts) decides nothing
    assert diagrams.decided_regions(grid + [_row("PT", 10, 0.1)], "shear_rate", "psi_bar") == []
    assert row_intervals([(4, "TT"), (11, "TT"), (13, "PT"), (20, "PT"), (30, "undecided"), (40, "PT")]) == [
        (4, 11, "TT"), (13, 20, "PT")]
    # two searches, S_C in (11, 13) at psi_bar = 0.3 and in (45, 55) at 0.5: TT below both brackets,
    # PT above both, the white between them holding the boundary
    search = {(4.0, 0.3): "TT", (11.0, 0.3): "TT", (13.0, 0.3): "PT", (100.0, 0.3): "PT",
              (4.0, 0.5): "TT", (45.0, 0.5): "TT", (55.0, 0.5): "PT", (100.0, 0.5): "PT"}
    assert row_regions(search) == [((4.0, 11.0, 0.3, 0.5), "TT"), ((55.0, 100.0, 0.3, 0.5), "PT")]
    flipped = {(y, x): outcome for (x, y), outcome in search.items()}
    assert row_regions(flipped, rows_along_x=False) == [((0.3, 0.5, 4.0, 11.0), "TT"), ((0.3, 0.5, 55.0, 100.0), "PT")]


def test_a_refinement_fills_the_cells_its_corners_decide():
    """refine.regions: the coarse cells split as the refinement split them; mixed cells stay white."""
    from hpcves.analysis.refine import Axis, RefineSettings, regions

    settings = RefineSettings(x=Axis("shear_rate", (10.0, 40.0), 0.8, log=True), y=Axis("psi_bar", (0.3, 0.5), 0.25),
                              max_cases=20)
    tt = {(10.0, 0.3): "TT", (10.0, 0.5): "TT", (40.0, 0.3): "TT", (40.0, 0.5): "TT"}
    assert regions(settings, tt) == [((10.0, 40.0, 0.3, 0.5), "TT")]
    mixed = {**tt, (40.0, 0.5): "PT"}
    assert regions(settings, mixed) == []                      # a mixed cell whose split has not run yet
    split = {**mixed, (20.0, 0.3): "TT", (20.0, 0.5): "TT"}
    assert regions(settings, split) == [((10.0, 20.0, 0.3, 0.5), "TT")]    # the half with TT corners only


def test_the_paper_diagram_is_a_column_wide_vector_figure(tmp_path):
    rows = [_row(regime, S, psi) for S, psi, regime in ((10, 0.3, "TT"), (40, 0.3, "TT"), (10, 0.5, "TT"),
                                                         (40, 0.5, "PT"))]
    fig = diagrams.paper_diagram(rows, "shear_rate", "psi_bar", [((10, 40, 0.3, 0.4), "TT")],
                                 lines=[[(30, 0.5), (40, 0.45)]], log_keys={"shear_rate"})
    assert tuple(fig.get_size_inches()) == (diagrams.PAPER_WIDTH, 0.8 * diagrams.PAPER_WIDTH)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_xlim()[0] < 10 and ax.get_xlim()[1] > 40
    assert not ax.collections                                   # no markers unless asked for
    fig.savefig(tmp_path / "p.pdf")
    assert b"/Subtype /Image" not in (tmp_path / "p.pdf").read_bytes()     # nothing rasterised
    marked = diagrams.paper_diagram(rows, "shear_rate", "psi_bar", [], markers=True)
    assert sum(len(c.get_offsets()) for c in marked.axes[0].collections) == 4


def test_the_critical_curve_breaks_where_a_search_did_not_converge():
    def search(psi, S_C, low, high):
        return {"psi_bar": psi, "S_C": S_C, "bracket_low": low, "bracket_high": high}
    searches = [search(0.25, 17.7, 17.5, 17.9), search(0.35, 11.9, 11.8, 12.0), search(0.45, math.nan, math.nan, 4.0),
                search(0.55, 4.6, 4.5, 4.7), search(0.65, 11.9, 11.8, 12.0)]
    fig, ax = plt.subplots()
    try:
        diagrams.mark_critical(ax, searches, "psi_bar")
        curves = [line for line in ax.get_lines() if line.get_marker() == "D"]
        assert [list(line.get_ydata()) for line in curves] == [[0.25, 0.35], [0.55, 0.65]]
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["S$_C$ bracket", "S$_C$"]
    finally:
        plt.close(fig)


def test_the_critical_shear_figure_shows_the_bending_energy_gap_beside_s_c():
    searches = [{"B2": b2, "S_C": s_c, "bracket_low": s_c * 0.99, "bracket_high": s_c * 1.01, "status": "converged",
                 "bending_gap": gap, "bending_gap_err": 0.01}
                for b2, s_c, gap in ((0.1, 70.6, 2.27), (0.7, 22.7, 0.74))]
    searches.append({"B2": 0.9, "S_C": math.nan, "bracket_low": math.nan, "bracket_high": 4.0, "status": "below",
                     "bending_gap": math.nan, "bending_gap_err": math.nan})
    fig = diagrams.critical_shear_figure(searches, "B2", title=diagrams.parameter_text({"psi_bar": 0.3}))
    try:
        left, right = fig.axes
        assert left.get_title() == r"$\bar\psi$ = 0.3" and "Delta E_b" in right.get_ylabel()
        gap_points = [line for line in right.get_lines() if line.get_marker() == "o"][0]
        assert np.allclose(gap_points.get_ydata(), [2.27, 0.74])
        assert np.all(np.abs(gap_points.get_xdata() - [0.1, 0.7]) < 0.02)     # dodged beside the diamonds
    finally:
        plt.close(fig)


def test_importing_the_figures_leaves_the_matplotlib_backend_alone():
    """A notebook's backend stays what it was: hpcves draws on Figure objects, not through pyplot."""
    import subprocess
    import sys

    code = ("import matplotlib; matplotlib.use('svg'); "
            "import hpcves.reports.case_figures, hpcves.reports.diagrams, hpcves.reports.analyze, "
            "hpcves.reports.figures, hpcves.cli; "
            "print(matplotlib.get_backend())")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "svg"


def test_a_figure_is_drawn_without_pyplot(tmp_path):
    """The figures are plain matplotlib Figures: saved as PNG, never registered with pyplot."""
    t = np.linspace(0.0, 2.0, 50)
    fig = diagrams.theta_curves([("S = 1", [(1.0, t, np.sin(t))])])
    fig.savefig(tmp_path / "theta.png", dpi=50)
    assert (tmp_path / "theta.png").stat().st_size > 1000
    assert fig not in [plt.figure(n) for n in plt.get_fignums()]


def test_a_boundary_is_smoothed_between_its_crossings_on_the_axes_scales():
    line = [(10.0, 0.3), (20.0, 0.3), (20.0, 0.5), (40.0, 0.5)]            # a staircase of cell edges
    xs, ys = diagrams.smoothed(line, (True, False))
    assert (xs[0], ys[0]) == pytest.approx((10.0, 0.3)) and (xs[-1], ys[-1]) == pytest.approx((40.0, 0.5))
    assert len(xs) == 16                                     # 4 points -> 2 + 2 x 3 -> 2 + 2 x 7
    assert np.all(np.diff(xs) >= -1e-12) and np.all(np.diff(ys) >= 0)        # a monotone staircase stays so
    assert 10.0 - 1e-12 <= xs.min() and xs.max() <= 40.0 + 1e-12 and 0.3 <= ys.min() and ys.max() <= 0.5
    # the corner at (20, 0.3) is cut: no point of the curve is on it; in log S the cut is symmetric
    assert not np.any(np.isclose(xs, 20.0) & np.isclose(ys, 0.3))
    first_cut = xs[1]
    assert first_cut == pytest.approx(10.0 * 2 ** (1 / 16))       # a quarter of a quarter of the way, in log S
    assert diagrams.smoothed([(1.0, 2.0), (3.0, 4.0)])[0].tolist() == [1.0, 3.0]  # a segment is left alone
