"""Overview of a campaign file: theta(t) and the last shape of every case.

    python analysis/plot_campaign.py out/demo/demo.h5 --out out/demo/overview.png [--cases DIR]

``--cases DIR`` also writes the one-page summary of every case (DIR/<id>.png).
The file may belong to a campaign that is still running.
"""
import argparse
import sys
from pathlib import Path

from hpcves.campaign.file import CampaignFile
from hpcves.model.params import ConfigError
from hpcves.reports.case_figures import campaign_figure, case_figure, case_title
from hpcves.run.store import STATUS_NAMES, open_file


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("campaign_file")
    parser.add_argument("--out", help="image file (PNG or PDF); default: next to the campaign file")
    parser.add_argument("--cases", help="directory for one summary figure per case")
    args = parser.parse_args(argv)
    try:
        with open_file(args.campaign_file, "r", locking=False) as h5:
            campaign = CampaignFile.check(h5, args.campaign_file)
            keys = campaign.sweep_keys
            cases = []
            for case_id in campaign.case_ids:
                store = campaign.store(case_id)
                snapshots = store.snapshots()
                last = {k: snapshots[k][-1] for k in ("x", "y", "psi")} if len(snapshots["t"]) else None
                attrs = dict(store.attrs)
                cases.append({"id": case_id, "status": STATUS_NAMES[store.status], "series": store.timeseries(),
                              "snapshots": snapshots, "last": last, "title": case_title(attrs),
                              **{k: attrs[f"physics.{k}"] for k in keys}})
            name = campaign.name
    except ConfigError as exc:
        sys.exit(f"Error: {exc}")
    out = Path(args.out) if args.out else Path(args.campaign_file).with_suffix(".png")
    campaign_figure(cases, keys, title=f"campaign {name!r}").savefig(out, dpi=110)
    print(out)
    if args.cases:
        directory = Path(args.cases)
        directory.mkdir(parents=True, exist_ok=True)
        for c in cases:
            path = directory / f"{c['id']}.png"
            case_figure(c["series"], c["snapshots"], title=f"case {c['id']}: {c['title']}").savefig(path, dpi=90)
        print(f"{directory}/<case>.png ({len(cases)} files)")


if __name__ == "__main__":
    main()
