"""Hand-written pieces against the well-kept libraries that could replace them -> BENCHMARKS.md.

    PYTHONPATH=/path/with/pydantic,msgspec,tqdm,rich python bench/bench_libraries.py --out BENCHMARKS.md

Neither pydantic, msgspec, tqdm nor rich is a dependency; a library that is not
importable gets a row that says so. For each piece: what it costs, and what a
user sees (the error message, the log file's lines), which is what decided.

* Config validation (config.py, model/params.py): a case from its TOML tables,
  with a type error and with two bad keys.
* Progress display (cli.terminal.StatusLine): what each writes into a SLURM log (not a
  terminal) over a run of 3000 steps, updated every step.
* Detrending and peak finding (analysis/periodicity.py) against scipy.signal:
  the same numbers? (They were, and faster: periodicity.py now calls scipy.signal.)
"""
from __future__ import annotations

import argparse
import dataclasses
import io
import sys
import time

import numpy as np

from hpcves.analysis import periodicity
from hpcves.config import case_from_dict, group_from_dict
from hpcves.model.params import Physics
from report import replace_section

CASE = {"physics": {"shear_rate": 80.0, "psi_bar": 0.3, "excess_length": 0.19385328260599, "B2": 0.3},
        "numerics": {"N": 128, "rtol": 1e-2}, "run": {"t_end": 4.0, "sample_interval": 0.01}}


def per_call(f, n=2000) -> float:
    """Median microseconds of f() over 5 blocks of n calls."""
    blocks = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(n):
            f()
        blocks.append((time.perf_counter() - start) / n * 1e6)
    return float(np.median(blocks))


def message(f) -> str:
    try:
        f()
    except Exception as exc:          # noqa: BLE001  (whatever each library raises)
        return " / ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return "(accepted)"


def config_rows() -> list:
    bad_type = {**CASE, "physics": {**CASE["physics"], "psi_bar": "0.3"}}
    bad_keys = {**CASE, "physics": {**CASE["physics"], "shear": 3.0, "tension": 1.0}}
    physics = CASE["physics"]
    rows = [["hpcves (config.group_from_dict; a whole case with case_from_dict: "
             f"{per_call(lambda: case_from_dict(CASE)):.0f} us)",
             f"{per_call(lambda: group_from_dict('physics', physics)):.0f} (physics only)",
             message(lambda: case_from_dict(bad_type)), message(lambda: case_from_dict(bad_keys))]]
    try:
        import typing

        import pydantic
        hints = typing.get_type_hints(Physics)
        model = pydantic.create_model(
            "Physics", __config__=pydantic.ConfigDict(strict=True, extra="forbid"),
            **{f.name: (hints[f.name], f.default) for f in dataclasses.fields(Physics)})

        def validate(values):                # types by pydantic, then the physics checks of the dataclass
            return Physics(**model.model_validate(values).model_dump())

        rows.append([f"pydantic {pydantic.VERSION} (a strict model of the Physics fields, then Physics)",
                     f"{per_call(lambda: validate(physics)):.0f} (physics only)",
                     message(lambda: validate(bad_type["physics"])), message(lambda: validate(bad_keys["physics"]))])
    except ImportError:
        rows.append(["pydantic", "not installed", "", ""])
    try:
        import msgspec
        rows.append([f"msgspec {msgspec.__version__} (convert to the Physics dataclass, strict)",
                     f"{per_call(lambda: msgspec.convert(physics, Physics)):.0f} (physics only)",
                     message(lambda: msgspec.convert(bad_type["physics"], Physics)),
                     message(lambda: msgspec.convert(bad_keys["physics"], Physics, forbid_unknown_fields=True)
                             if "forbid_unknown_fields" in msgspec.convert.__doc__ else
                             msgspec.convert(bad_keys["physics"], Physics))])
    except ImportError:
        rows.append(["msgspec", "not installed", "", ""])
    return rows


class _File(io.StringIO):
    def isatty(self):
        return False


def progress_rows(steps: int = 3000) -> list:
    sys.path.insert(0, ".")
    from hpcves.cli.terminal import ProgressLine
    from hpcves.run.runner import Tick

    rows = []
    out = _File()
    line = ProgressLine(stream=out)
    line.LOG_SECONDS = 0.05                 # 30 s in use; scaled with the run below (3000 steps ~ 1.5 s)
    start = time.perf_counter()
    for i in range(steps):
        line(Tick(t=i * 1e-3, t_end=3.0, steps_per_second=2000.0, eta_seconds=1.0, theta=0.5))
        time.sleep(0.0005)
    line.close()
    wall = time.perf_counter() - start
    text = out.getvalue()
    rows.append(["hpcves (cli.terminal.StatusLine: a line every LOG_SECONDS off a terminal)", str(text.count("\n")),
                 str(text.count("\r")), str(len(text))])
    try:
        import tqdm
        out = _File()
        for _ in tqdm.tqdm(range(steps), file=out, mininterval=0.05 * 0.5 / 30 * 30, miniters=1):
            time.sleep(wall / steps)
        text = out.getvalue()
        rows.append([f"tqdm {tqdm.__version__} (mininterval as above)", str(text.count("\n")), str(text.count("\r")),
                     str(len(text))])
    except ImportError:
        rows.append(["tqdm", "not installed", "", ""])
    try:
        from rich.console import Console
        from rich.progress import track
        out = _File()
        for _ in track(range(steps), console=Console(file=out), refresh_per_second=20):
            time.sleep(wall / steps)
        text = out.getvalue()
        from importlib.metadata import version
        rows.append([f"rich {version('rich')} (progress.track)",
                     str(text.count("\n")), str(text.count("\r")), str(len(text))])
    except ImportError:
        rows.append(["rich", "not installed", "", ""])
    return rows


def signal_rows() -> list:
    import scipy.signal

    t = np.linspace(0.0, 40.0, 20001)
    x = 0.3 + 0.05 * np.sin(2 * np.pi * t / 1.7) + 0.002 * t + 1e-5 * np.random.default_rng(1).standard_normal(t.size)
    def polyfit_detrend(x):             # what periodicity.detrend was
        i = np.arange(x.size, dtype=float)
        slope, intercept = np.polyfit(i, x, 1)
        return x - (slope * i + intercept)

    ours, theirs = polyfit_detrend(x), scipy.signal.detrend(x, type="linear")
    rows = [["detrend (least-squares line)", f"{per_call(lambda: polyfit_detrend(x), 200):.0f}",
             f"{per_call(lambda: scipy.signal.detrend(x, type='linear'), 200):.0f}",
             f"max difference {np.max(np.abs(ours - theirs)):.1e}"]]
    r = periodicity.autocorrelation(periodicity.detrend(x))
    k = np.arange(1, r.size - 1)

    def mask():                         # what periodicity.acf_period did
        return k[(r[k] >= r[k - 1]) & (r[k] > r[k + 1]) & (r[k] > 0)]

    found, their = mask(), scipy.signal.find_peaks(r, height=0)[0]
    same = np.array_equal(found, their)
    rows.append(["autocorrelation peaks (local maxima above 0)", f"{per_call(mask, 200):.0f}",
                 f"{per_call(lambda: scipy.signal.find_peaks(r, height=0), 200):.0f}",
                 f"{found.size} peaks, " + ("the same" if same else f"different ({their.size} found by scipy)")])
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="BENCHMARKS.md")
    args = parser.parse_args(argv)
    from hpcves.reports.tables import markdown_table

    started = time.perf_counter()
    config, progress, signal = config_rows(), progress_rows(), signal_rows()
    lines = ["## Hand-written pieces against libraries", "",
             f"Run {time.strftime('%Y-%m-%d %H:%M')} by `bench/bench_libraries.py` "
             f"({time.perf_counter() - started:.0f} s), same machine as above. Why each is kept: "
             "docs/design.md, \"Libraries\".", "",
             "Config validation: microseconds a call (median), and the message for `psi_bar = \"0.3\"` "
             "(a string) and for two unknown keys in [physics].", "",
             markdown_table(["validator", "us a case", "a wrong type", "two unknown keys"], config), "",
             "Progress display into a file that is not a terminal (a SLURM log): 3000 updates over ~2 s, "
             "hpcves's interval scaled from its 30 s to 0.05 s.", "",
             markdown_table(["display", "lines", "carriage returns", "bytes"], progress), "",
             "Signal pieces: the hand-written ones hpcves had against scipy.signal, which periodicity.py "
             "now uses, on 20001 samples (microseconds a call, median).", "",
             markdown_table(["piece", "hand-written us", "scipy.signal us", "result"], signal), ""]
    section = "\n".join(lines)
    print(section)
    replace_section(args.out, "Hand-written pieces against libraries", section)


if __name__ == "__main__":
    main()
