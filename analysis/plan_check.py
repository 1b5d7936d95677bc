"""The plan of a study (hpcves campaign --plan) against what its campaign took.

    python analysis/plan_check.py jobs/demo.toml out/demo/demo.h5 [STUDY FILE ...]

For each pair: the cases planned (known, at most) and run; the core-hours of the
plan (likely, ceiling) and of the campaign (the wall time of every case, summed);
the steps each case took against ``Case.estimated_steps`` scaled to how far it ran;
and the shear times a case running until decided took, over decided_shear_times
(what plan.DECIDED_AFTER is the median of). A Markdown table on stdout. Run it on
an idle machine: the step is timed here, and the campaign's walls are its own.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from hpcves.campaign.file import read_table
from hpcves.campaign.plan import plan
from hpcves.campaign.study import load_study
from hpcves.reports.tables import markdown_table
from hpcves.run.runner import one_thread
from hpcves.run.timing import StepCost


def compare(study_file: str, campaign_file: str, cost: StepCost) -> tuple[list, np.ndarray]:
    study = load_study(study_file)
    estimate = plan(study, cost)
    rows = read_table(campaign_file).rows
    wall = np.array([r["wall"] for r in rows])
    steps = wall * np.array([r["steps_per_second"] for r in rows])
    t = np.array([r["t"] for r in rows])
    t_end = np.array([r["t_end"] for r in rows])
    cases = [study.make_case("check", {k: r[k] for k in study.sweep_keys}).case for r in rows]
    expected = np.array([c.estimated_steps for c in cases]) * t / t_end       # to where each case stopped
    decided = np.array([])
    if study.base.run.until_decided:
        shear = np.array([r["t"] * r["shear_rate"] for r in rows]) / study.base.run.decided_shear_times
        decided = shear[t < 0.999 * t_end]
    likely = (estimate.likely or estimate).core_seconds / 3600
    ratio = steps / expected
    row = [study.name, f"{estimate.first.cases} / {estimate.cases}", str(len(rows)),
           f"{likely:.3g}", f"{estimate.core_seconds / 3600:.3g}", f"{wall.sum() / 3600:.3g}",
           f"{likely / (wall.sum() / 3600):.2f}",
           f"{np.median(ratio):.2f} [{ratio.min():.2f}, {ratio.max():.2f}]",
           f"{np.median(decided):.2f} ({decided.size})" if decided.size else "-"]
    return row, decided


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pairs", nargs="+", help="STUDY.toml CAMPAIGN.h5, one pair after the other")
    args = parser.parse_args(argv)
    if len(args.pairs) % 2:
        parser.error("give the study files and campaign files in pairs")
    one_thread()
    cost = StepCost(announce=lambda text: print(text, file=sys.stderr))
    rows, decided = [], []
    for study_file, campaign_file in zip(args.pairs[::2], args.pairs[1::2]):
        row, shear = compare(study_file, campaign_file, cost)
        rows.append(row)
        decided.append(shear)
    print(markdown_table(["study", "cases planned (known / at most)", "cases run", "core-h likely", "core-h ceiling",
                          "core-h taken", "likely / taken", "steps / expected: median [range]",
                          "decided after (x decided_shear_times): median (cases)"], rows))
    pooled = np.concatenate(decided)
    if pooled.size:
        print(f"\nDecided after {np.median(pooled):.2f} x decided_shear_times shear times (median of "
              f"{pooled.size} cases that stopped early; 10 % to 90 %: {np.quantile(pooled, 0.1):.2f} to "
              f"{np.quantile(pooled, 0.9):.2f}, largest {pooled.max():.2f})")


if __name__ == "__main__":
    main()
