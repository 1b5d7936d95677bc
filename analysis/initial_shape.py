"""The two starts of a deflated vesicle -> docs/initial_shape.md and docs/initial_shape.png.

1. The shapes: for each excess length, the ellipse's tip curvature a/b^2 against the
   smoothed start's (physics.initial_shape = "smoothed", geometry.smoothed_ellipse), the
   factor c that gives back the ellipse's area, the smoothed start's least curvature
   (negative: concave flanks) and the excess length it keeps.
2. The two deflated cases the publication shows at psi_bar = 0.48 (its Fig. 8: Delta = 0.94,
   S = 4; its Fig. 9: Delta = 2.3, S = 28), each from the ellipse (hpcves's default start)
   and from the smoothed shape with the phase in the ellipse's parameter (the authors' start),
   and from the smoothed shape with the phase in arclength (the shape alone changed), run until
   decided as ``hpcves run`` runs them (N = 128, rtol = 1e-3): regime, period, inclination and
   the soft domains of the pattern (analysis/pattern.py) over the settled record.

    .venv/bin/python analysis/initial_shape.py --jobs 2      (~3 min on 2 cores)
"""
from __future__ import annotations

import argparse
import datetime
import multiprocessing
import platform
import sys
import time
from pathlib import Path

import numpy as np

from hpcves.analysis.pattern import soft_domains
from hpcves.analysis.regimes import classify
from hpcves.model import geometry
from hpcves.model.params import REFERENCE_LENGTH, Case, Numerics, Physics, RunControl
from hpcves.numerics.spectral import Spectral
from hpcves.reports.case_figures import shape_strip
from hpcves.reports.tables import markdown_table
from hpcves.run.casefile import create_case_file, run_file
from hpcves.run.runner import one_thread
from hpcves.run.store import CaseStore, open_file

one_thread()

SHAPES = (0.19385328260599, 0.94, 2.3, 3.0)
#: (Delta, S, shear times at most): the publication's Figs 8 and 9, psi_bar = 0.48
CASES = ((0.94, 4.0, 1000.0), (2.3, 28.0, 1000.0))
#: (label, initial_shape, psi_init_coordinate)
STARTS = (("ellipse", "ellipse", "arclength"), ("authors' start", "smoothed", "ellipse_parameter"),
          ("smoothed shape", "smoothed", "arclength"))
PSI_BAR, N, RTOL = 0.48, 128, 1e-3


def shape_row(delta: float) -> list[str]:
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, delta)
    sp = Spectral(1024, REFERENCE_LENGTH, backend="numpy")
    theta = geometry.smoothed_ellipse(a, b, sp.N)
    curvature = 2 * np.pi / sp.length + sp.ds(theta - sp.circle_angle)
    excess = np.fft.rfft(theta - np.pi / 2 - sp.circle_angle)[2] / sp.N
    c = (excess / geometry.ellipse_angle_modes(a, b)[4 + 2]).real
    kept = geometry.excess_length(geometry.enclosed_area(theta, sp), sp.length) - delta
    return [f"{delta:.4g}", f"{b / a:.4f}", f"{a / b**2:.2f}", f"{c:.4f}", f"{curvature.max():.3f}",
            f"{curvature.min():.3f}", f"{kept:.1e}"]


def run_case(job: tuple) -> dict:
    (delta, S, shear_times), (label, shape, coordinate), out = job
    t_end = max(4.0, shear_times / S)
    case = Case(Physics(shear_rate=S, psi_bar=PSI_BAR, excess_length=delta, initial_shape=shape,
                        psi_init_coordinate=coordinate),
                Numerics(N=N, rtol=RTOL),
                RunControl(t_end=t_end, sample_interval=min(0.02, 0.1 / S), snapshot_interval=min(0.02, 0.1 / S),
                           checkpoint_interval=t_end, until_decided=True))
    path = out / f"delta{delta:g}_S{S:g}_{shape}_{coordinate}.h5"
    start = time.monotonic()
    outcome = run_file(create_case_file(path, case, overwrite=True), resume=False)
    wall = time.monotonic() - start
    with open_file(path, "r") as h5:
        store = CaseStore.open(h5, where=str(path))
        series, snapshots = store.timeseries(), store.snapshots()
    found = classify(series)
    settled = snapshots["t"] >= found.t_settle if np.isfinite(found.t_settle) else snapshots["t"] >= 0.5 * outcome.t
    counts = [len(soft_domains(psi)) for psi in snapshots["psi"][settled]]
    return dict(delta=delta, S=S, label=label, shape=shape, coordinate=coordinate, path=path, t=outcome.t,
                wall=wall, found=found, domains=(min(counts), max(counts)) if counts else None,
                first_domains=len(soft_domains(snapshots["psi"][0])), psi_max=float(np.max(snapshots["psi"])))


def outcome_row(r: dict) -> list[str]:
    f = r["found"]
    period = f"{f.period:.5g} +- {f.period_err:.1g}" if np.isfinite(f.period) else ""
    low, high = r["domains"] or (None, None)
    domains = "" if low is None else (f"{low}" if low == high else f"{low}-{high}")
    return [f"{r['delta']:g}", f"{r['S']:g}", r["label"], f.regime, f"{r['t']:.4g}", f"{f.theta_mean:.4f}", period,
            f"{f.theta_min:.3f}", domains, f"{r['wall']:.0f}"]


def figure(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    deflated = [r for r in results if r["delta"] == 2.3 and r["coordinate"] != "arclength" or
                r["delta"] == 2.3 and r["shape"] == "ellipse"]
    fig = Figure(figsize=(11, 2.6 + 1.8 * len(deflated)))
    axes = fig.subplots(1 + len(deflated), 1, squeeze=False, height_ratios=[1.4] + [1.0] * len(deflated))[:, 0]
    ax = axes[0]
    sp = Spectral(512, REFERENCE_LENGTH, backend="numpy")
    for k, delta in enumerate((0.94, 2.3)):
        a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, delta)
        t = 2 * np.pi * np.arange(512) / 512
        ax.plot(a * np.cos(t) + 1.3 * k, b * np.sin(t), "k--", lw=1, label="ellipse" if k == 0 else None)
        z = sp.antiderivative_complex(np.exp(1j * geometry.smoothed_ellipse(a, b, sp.N)), 0.0)
        z = np.r_[z, z[0]] - z.mean()
        ax.plot(z.real + 1.3 * k, z.imag, "C3", lw=2, label="smoothed (authors' start)" if k == 0 else None)
        ax.text(1.3 * k, -0.29, f"$\\Delta$ = {delta:g}", ha="center")
    ax.set_aspect("equal")
    ax.axis("off")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    ax.set_title("the two starts at the same length and area", loc="left")
    mappable = None
    for ax, r in zip(axes[1:], deflated):
        with open_file(r["path"], "r") as h5:
            snapshots = CaseStore.open(h5, where=str(r["path"])).snapshots()
        times = snapshots["t"]
        wanted = [0.0, 0.01, 0.1, 0.3, 1.0, times[-1] - 0.3, times[-1]]
        indices = sorted({int(np.argmin(np.abs(times - w))) for w in wanted})
        mappable = shape_strip(ax, snapshots, indices)
        f = r["found"]
        ax.set_title(f"$\\Delta$ = 2.3, S = 28, $\\bar\\psi$ = 0.48, from the {r['label']}: {f.regime}"
                     + (f", period {f.period:.4g}" if np.isfinite(f.period) else ""), loc="left")
    if mappable is not None:
        fig.colorbar(mappable, ax=list(axes[1:]), label=r"$\psi$ (1: soft)", shrink=0.6)
    fig.savefig(path, dpi=100, bbox_inches="tight")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="docs/initial_shape.md")
    parser.add_argument("--runs", default="out/initial_shape", help="folder for the case files")
    args = parser.parse_args(argv)
    runs = Path(args.runs)
    runs.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    shapes = [shape_row(delta) for delta in SHAPES]
    jobs = [(case, s, runs) for case in CASES for s in STARTS]
    with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
        results = []
        for r in pool.imap(run_case, jobs):
            print(f"Delta = {r['delta']:g}, S = {r['S']:g}, {r['label']}: {r['found'].regime} at t = {r['t']:.4g} "
                  f"({r['wall']:.0f} s)", flush=True)
            results.append(r)
    png = Path(args.out).with_suffix(".png")
    figure(results, png)
    lines = [
        "# The two starts of a deflated vesicle",
        "",
        f"Written by `analysis/initial_shape.py` on {datetime.date.today()} ({platform.node()}, "
        f"{time.monotonic() - start:.0f} s on {args.jobs} processes); docs/numerics.md, \"Initial shape\", "
        "says what the smoothed start is and why it matters.",
        "",
        "## The shapes (length 2.6442)",
        "",
        "Curvature on 1024 nodes; c the factor of the kept modes that restores the ellipse's area; the last "
        "column the smoothed start's excess length minus the ellipse's.",
        "",
        markdown_table(["Delta", "b/a", "ellipse tip", "c", "smoothed tip", "smoothed least", "Delta kept"], shapes),
        "",
        f"## The publication's two deflated cases (psi_bar = {PSI_BAR}, N = {N}, rtol = {RTOL:g}, until decided)",
        "",
        "Soft domains: arcs with psi > 1/2, over the snapshots of the settled record (from t_settle; the "
        "second half of the run where it is not settled). The authors' start is the smoothed shape with the "
        "phase in the ellipse's parameter; 'smoothed shape' changes the shape alone.",
        "",
        markdown_table(["Delta", "S", "start", "regime", "decided at t", "theta", "period", "theta min",
                        "soft domains", "wall (s)"], [outcome_row(r) for r in results]),
        "",
        "largest psi on any snapshot: " + ", ".join(f"{r['label']} at Delta = {r['delta']:g} {r['psi_max']:.3f}"
                                                   for r in results),
        "",
        f"![the two starts, and the pattern that forms from each at Delta = 2.3, S = 28]({png.name})",
        "",
    ]
    Path(args.out).write_text("\n".join(lines))
    print(f"{args.out}, {png}")


if __name__ == "__main__":
    sys.exit(main())
