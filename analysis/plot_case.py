"""Summary figure of one case file: ``python analysis/plot_case.py case.h5 --out case.png``."""
import argparse
import sys
from pathlib import Path

from hpcves.model.params import ConfigError
from hpcves.reports.case_figures import case_figure, case_title
from hpcves.run.store import CaseStore, open_file


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("case_file")
    parser.add_argument("--out", help="image file (PNG or PDF); default: next to the case file")
    args = parser.parse_args(argv)
    try:
        with open_file(args.case_file, "r") as h5:
            store = CaseStore.open(h5, where=args.case_file)
            series, snapshots = store.timeseries(), store.snapshots()
            title = case_title(h5.attrs)
    except ConfigError as exc:
        sys.exit(f"Error: {exc}")
    out = Path(args.out) if args.out else Path(args.case_file).with_suffix(".png")
    case_figure(series, snapshots, title=title).savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
