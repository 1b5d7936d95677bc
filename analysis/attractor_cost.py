"""What an attractor map costs against a single-start refinement (#38 item 8) -> docs/attractor_cost.md.

For every deflated study of ``make reproduce`` whose two twins (from the ellipse, and from the authors'
smoothed start) have run and been analysed (out/reproduce/<grid>/<study>/regimes.csv and
boundaries.csv), three ways to learn where the starts reach different attractors:

* **one start**: the ellipse's refinement alone (no attractors at all);
* **both refined**: each start refined on its own (the twins: what make reproduce runs);
* **second start at coarse points and crossing ends**: the ellipse's refinement, plus the authors'
  start run only at the coarse grid and at both ends of every crossing the ellipse's refinement found
  (the cost of those runs is taken from the twin where it ran the same point; a point the twin did
  not run is counted at the twin's median cost per case).

Compute is the sum of every case's wall seconds (from the campaign files). The points with two
attractors are those the two refinements share where the starts reach a different regime or pattern
topology (attractor_map.compare(values=False), as REPRODUCTION.md counts them); the cheap scheme finds
those of them that lie on its point set.

    .venv/bin/python analysis/attractor_cost.py       (seconds: it reads what make reproduce wrote)
"""
from __future__ import annotations

import csv
import datetime
import math
import platform
from pathlib import Path

import numpy as np

from hpcves.campaign.file import read_table
from hpcves.campaign.study import load_study
from hpcves.reports.attractor_map import compare
from hpcves.reports.tables import markdown_table

ROOT = Path(__file__).resolve().parent.parent
STUDIES = ("psi048_delta_S", "delta094_S_psi", "delta230_S_psi")
TEXT = ("case", "status", "regime", "reason")


def rows_of(path: Path) -> list[dict]:
    """regimes.csv as rows, numbers as floats (empty cells: nan)."""
    with open(path) as f:
        return [{k: (v if k in TEXT or k == "start" else float(v) if v else math.nan) for k, v in r.items()}
                for r in csv.DictReader(f)]


def crossing_ends(path: Path, x_key: str, y_key: str) -> set:
    """Both ends of every crossing of boundaries.csv."""
    with open(path) as f:
        return {(round(float(r[f"{x_key}_{a}"]), 6), round(float(r[f"{y_key}_{b}"]), 6))
                for r in csv.DictReader(f) for a, b in (("low", "low"), ("high", "high"))}


def study_cost(name: str, grid: str) -> dict | None:
    jobs = ROOT / "jobs" / "reproduce" / ("fine" if grid == "fine" else "")
    out = ROOT / "out" / "reproduce" / grid
    ellipse, authors = load_study(jobs / f"{name}.toml"), load_study(jobs / f"{name}_smoothed.toml")
    paths = [out / n / "regimes.csv" for n in (name, f"{name}_smoothed")] + [out / name / "boundaries.csv"]
    if not all(p.exists() for p in paths) or not all(Path(s.output).exists() for s in (ellipse, authors)):
        return None
    x_key, y_key = ellipse.refine.axes
    walls = {}
    for study, label in ((ellipse, "ellipse"), (authors, "authors")):
        walls[label] = {r["case"]: r["wall"] for r in read_table(study.output).rows}
    rows = {"ellipse": rows_of(paths[0]), "authors": rows_of(paths[1])}

    def point(r):
        return round(r[x_key], 6), round(r[y_key], 6)

    cost_at = {}                                   # the authors' start: compute at each point it ran (all runs)
    for r in rows["authors"]:
        cost_at[point(r)] = cost_at.get(point(r), 0.0) + walls["authors"][r["case"]]
    median = float(np.median(list(walls["authors"].values())))
    coarse = {(round(x, 6), round(y, 6)) for x in ellipse.sweep[x_key] for y in ellipse.sweep[y_key]}
    cheap_points = coarse | crossing_ends(paths[2], x_key, y_key)
    cheap_second = sum(cost_at.get(p, median) for p in cheap_points)
    missing = sum(p not in cost_at for p in cheap_points)
    one = sum(walls["ellipse"].values())
    both = one + sum(walls["authors"].values())
    compared = compare(rows, values=False)
    shared = [c for c in compared if "ellipse" in c["rows"] and "authors" in c["rows"]]
    decided = [c for c in shared if sum(len(a.runs) for a in c["attractors"]) == 2]
    differ = [c for c in decided if len(c["attractors"]) > 1]
    found = [c for c in differ if (round(c[x_key], 6), round(c[y_key], 6)) in cheap_points]
    return {"study": name, "ellipse cases": len(rows["ellipse"]), "authors cases": len(rows["authors"]),
            "other regimes": sum(r["regime"] in ("PT", "TU") for r in rows["authors"]),
            "one": one, "both": both, "cheap": one + cheap_second, "cheap points": len(cheap_points),
            "missing": missing, "shared": len(shared), "decided": len(decided), "differ": len(differ),
            "found": len(found)}


def main() -> None:
    results = [r for r in (study_cost(name, "coarse") for name in STUDIES) if r is not None]
    body = []
    for r in results:
        body.append([r["study"], f"{r['ellipse cases']} / {r['authors cases']}", f"{r['one']:.0f}",
                     f"{r['both']:.0f} ({r['both'] / r['one']:.2f}x)",
                     f"{r['cheap']:.0f} ({r['cheap'] / r['one']:.2f}x; {r['cheap points']} points"
                     + (f", {r['missing']} at the median cost" if r["missing"] else "") + ")",
                     f"{r['differ']} of {r['decided']}", f"{r['found']} of {r['differ']}"])
    text = [
        "# What an attractor map costs (make reproduce, coarse set)", "",
        f"Written by analysis/attractor_cost.py on {datetime.date.today()} ({platform.node()}), from the "
        "campaign files and analyses make reproduce left in out/reproduce/coarse. Compute: the sum of the "
        "cases' wall seconds on one core each. \"Second start at coarse points and crossing ends\": the "
        "ellipse's refinement plus the authors' start run only at the coarse grid and at both ends of every "
        "crossing the ellipse's refinement found. Points with two attractors: the points both refinements "
        "ran and decided where the two starts reach a different regime or pattern topology.", "",
        markdown_table(["study", "cases (ellipse / authors')", "one start (s)", "both refined (s)",
                        "second start at coarse points and crossing ends (s)",
                        "points with two attractors (of those both decided)", "found by the cheaper scheme"],
                       body), "",
        "The cheaper scheme finds the coexistence that lies on the ellipse's own boundaries and coarse grid; "
        "a region where only the authors' start changes regime (its own boundaries: the phase-treading band "
        "and tumbling at Delta = 2.3, which the ellipse's refinement never crosses) it misses by "
        "construction. That is why make reproduce refines both starts. At Delta = 2.3 the ellipse tank-treads "
        "at all its 15 points, while the authors' start phase-treads or tumbles at "
        + ", ".join(f"{r['other regimes']} of {r['authors cases']} cases ({r['study']})" for r in results
                    if r["study"].startswith("delta230")) + ": there the map from both refinements shows a "
        "coexistence region the cheaper scheme cannot see.", ""]
    (ROOT / "docs" / "attractor_cost.md").write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
