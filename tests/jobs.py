"""Real ``hpcves`` processes for the tests: start, find, wait for, kill, and compare what they wrote.

Everything here waits for *states* (a file, a status in it, processes gone), never for a time:
the machines are shared and slow down without warning. A timeout only guards against a hang.
"""
import contextlib
import os
import shutil
import subprocess
import sys
import time

import h5py
import numpy as np

from hpcves.campaign import file as campaign_file
from hpcves.files import atomic

HPCVES = [sys.executable, "-m", "hpcves.cli"]
MPIRUN = shutil.which("mpirun")
HANG = float(os.environ.get("HPCVES_TEST_HANG", 300.0))      # seconds: only a hang takes this long


@contextlib.contextmanager
def writing_format(version):
    """Campaign files written as an older hpcves wrote them: format 2 (blocks, a dataset a record) or
    format 1 (a group per case, in HDF5's earliest file formats: h5py's default libver)."""
    saved = campaign_file.WRITES_VERSION, atomic.FILE_FORMAT
    campaign_file.WRITES_VERSION = version
    if version == 1:
        atomic.FILE_FORMAT = ("earliest", "v110")
    try:
        yield
    finally:
        campaign_file.WRITES_VERSION, atomic.FILE_FORMAT = saved


def mpi_env(**extra):
    env = dict(os.environ)
    env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMPI_MCA_pml="ob1", OMPI_MCA_btl="self,vader",
               OMPI_MCA_btl_vader_single_copy_mechanism="none")
    env.update(extra)
    return env


def command(n, *args):
    return ([MPIRUN, "-n", str(n)] if n else []) + HPCVES + [str(a) for a in args]


def hpcves(*args, n=None, timeout=HANG, env=None):
    return subprocess.run(command(n, *args), capture_output=True, text=True, timeout=timeout,
                          env=env or mpi_env())


def start_job(n, *args, env=None, own_group=False):
    """The command running in the background; ``own_group``: in a process group of its own, led by it
    (as a shell with job control starts it), so that ``kill -- -PGID`` reaches it and not the tests."""
    return subprocess.Popen(command(n, *args), env=env or mpi_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, process_group=0 if own_group else None)


def job_pids(root_pid):
    """``root_pid`` and every process it started (mpirun's ranks run in process groups of their own)."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parents[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    found, frontier = {root_pid}, [root_pid]
    while frontier:
        pid = frontier.pop()
        for child, parent in parents.items():
            if parent == pid and child not in found:
                found.add(child)
                frontier.append(child)
    return found


def alive(pid) -> bool:
    """Whether ``pid`` is a process that has not ended (zombies count as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def wait_until(condition, what, timeout=HANG, poll=0.02):
    """Poll ``condition`` until it is true; fail after ``timeout`` (a hang), saying what never happened."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting until {what}")
        time.sleep(poll)


def signal_job(job, signum, *, ranks_only=False):
    """Send ``signum`` to the job's processes (all of them, or only those below mpirun); their pids."""
    pids = job_pids(job.pid)
    if ranks_only:
        pids.discard(job.pid)
    for pid in pids:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass
    return pids


def freeze_when(job, condition, what, timeout=HANG):
    """Wait until ``condition`` holds, then stop the job's ranks (SIGSTOP) with it still holding.

    The check is repeated once the ranks are frozen, so the state cannot move on between the check
    and whatever the test does next; if it moved on in the meantime, the ranks are let go again
    and the wait goes on. Returns the frozen pids (``thaw`` them, or kill them).
    """
    import signal

    deadline = time.monotonic() + timeout
    while True:
        wait_until(condition, what, timeout=max(deadline - time.monotonic(), 0.1))
        pids = signal_job(job, signal.SIGSTOP, ranks_only=True)
        wait_until(lambda: all(_state(p) in ("T", "t", "Z", None) for p in pids), "the ranks are stopped")
        if condition():
            return pids
        thaw(pids)


def thaw(pids):
    import signal

    for pid in pids:
        try:
            os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            pass


def _state(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return None


def kill_job(job):
    """SIGKILL every process of the job and wait until none is left."""
    import signal

    pids = signal_job(job, signal.SIGKILL)
    job.communicate()
    wait_until(lambda: not any(alive(p) for p in pids), "the killed job's processes are gone")


class CaseView:
    """One case of an open campaign file of either layout (a group per case, or a row of its block's
    arrays): ``view[path]`` is the case's array at ``path`` ("status", "timeseries/theta"), ``view[path]
    = value`` writes it, ``view.attrs`` its attributes (a row's: the store's), ``view.names()`` its
    datasets, ``view.path(name)`` where in the file the dataset lies."""

    def __init__(self, f, case_id, campaign=None):
        from hpcves.campaign.file import CampaignFile

        store = (campaign or CampaignFile(f)).store(case_id)
        self.store = store
        self.attrs = dict(store.attrs)
        if store.group is not None:
            self.group, self.row = store.group, None
        else:
            self.group, self.row = store._place.block, store._place.prefix[0]

    def _column(self, name):
        return self.store._place.column(name)

    def path(self, name):
        column = self._column(name)
        return f"{self.group.name}/{column.array if column else name}"

    def __getitem__(self, name):
        column = self._column(name)
        d = self.group[column.array if column else name]
        value = np.asarray(d[()] if self.row is None else d[self.row])
        return value if column is None else np.ascontiguousarray(value[column.index()])

    def __setitem__(self, name, value):
        column = self._column(name)
        if column is not None:                  # a record of a packed array (campaign format 3)
            whole = self.group[column.array][self.row]
            whole[column.index()] = value
            name, value = column.array, whole
        d = self.group[name]
        if self.row is None:
            d[()] = value
        else:
            d[self.row] = value

    def __contains__(self, name):
        column = self._column(name)
        return (column.array if column else name) in self.group

    def names(self):
        """Its records (a packed array's as the records it holds, so files of every layout compare)."""
        found = []
        self.group.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) else None)
        in_group = ("snapshots/alpha", "timeseries/xy", "timeseries/sample", "snapshots/snapshot")
        in_block = ("case", "sample", "snapshot", "alpha", "xy", "timeseries/quantity", "timeseries/long_name",
                    "timeseries/units", "snapshots/field", "snapshots/long_name", "snapshots/units", "checkpoint/array")
        scales = in_group if self.row is None else in_block
        records = {}
        for record, column in getattr(self.store._place, "_columns", {}).items():
            records.setdefault(column.array, []).append(record)
        return [record for n in found if n not in scales for record in records.get(n, [n])]


def case_view(f, case_id):
    return CaseView(f, case_id)


def case_views(f):
    """(case id, CaseView) of every case of an open campaign file, in id order."""
    from hpcves.campaign.file import CampaignFile

    campaign = CampaignFile(f)
    return [(case_id, CaseView(f, case_id, campaign)) for case_id in campaign.case_ids]


def case_statuses(path):
    """{case id: status} of a campaign file, read as a reader of a live file would (no lock)."""
    with h5py.File(path, "r", locking=False) as f:
        return {case_id: int(g["status"][()]) for case_id, g in case_views(f)}


def running_cases(path, *, checkpointed=False, sampled=False):
    """Cases with status 1 (running), if ``checkpointed`` with a valid checkpoint, if ``sampled`` with samples
    written; [] while the file does not exist yet (it appears complete: hpcves/files/atomic.py)."""
    if not os.path.exists(path):
        return []
    with h5py.File(path, "r", locking=False) as f:
        out = []
        for case_id, g in case_views(f):
            if int(g["status"][()]) != 1:
                continue
            if checkpointed and not any(g[f"checkpoint/{s}/meta"][0] == 1 for s in ("slot0", "slot1")):
                continue
            if sampled and int(g["timeseries/length"][()]) == 0:
                continue
            out.append(case_id)
        return out


# ---------------------------------------------------------------------- what a campaign wrote
DETERMINED = {"progress": slice(0, 2)}      # t and t_end; wall seconds and steps/s differ between any two runs


def newest_checkpoint(g):
    metas = {s: g[f"checkpoint/{s}/meta"] for s in ("slot0", "slot1")}
    valid = [(m[1], s) for s, m in metas.items() if m[0] == 1]
    if not valid:
        return {}
    slot = max(valid)[1]
    return {f"checkpoint/{name.split('/', 2)[2]}": g[name] for name in g.names()
            if name.startswith(f"checkpoint/{slot}/")}


def results(path):
    """Every dataset and attribute of a campaign file that the computation determines.

    Left out: the wall-clock part of ``progress``, which checkpoint slot holds what (a stop writes an
    extra checkpoint; the newest valid checkpoint is compared instead), the campaign file's text
    (it names the output path) and its checksum, the file's format version and where the data lie in the file
    (index/addresses: the root's attributes come first, and that text's length shifts everything
    after them; format 2's index/block and index/row) -- so files of either layout compare.
    """
    out = {}
    with h5py.File(path, "r", locking=False) as f:
        out["/attrs"] = {k: v for k, v in f.attrs.items()
                         if k not in ("hpcves_version", "campaign_toml", "campaign_toml_sha256", "format_version")}
        for name, d in f["index"].items():
            if name == "verdict":                 # the codes; the wall seconds they were stored with vary
                out[f"/index/{name}"] = d[:, 0]
            elif name not in ("addresses", "block", "row", "config"):     # where a case lies (its config:
                out[f"/index/{name}"] = d[()]                             # its attrs, below, either layout)
        for case_id, g in case_views(f):
            data = {"attrs": {k: v for k, v in g.attrs.items() if k != "hpcves_version"}}
            for name in g.names():
                if not name.startswith("checkpoint/"):
                    value = g[name]
                    data[name] = value[DETERMINED[name]] if name in DETERMINED else value
            data.update(newest_checkpoint(g))
            out[case_id] = data
    return out


def differences(a, b, attrs=True):
    """[(where, what)] between the results of two files; empty if they agree bit for bit.

    ``attrs=False`` leaves out the attributes (the parameters): for files of studies that differ only
    in how they record, such as their checkpoint interval.
    """
    ra, rb = results(a), results(b)
    if not attrs:
        for r in (ra, rb):
            r.pop("/attrs")
            for key in r:
                if not key.startswith("/"):
                    r[key].pop("attrs")
    found = []
    if ra.keys() != rb.keys():
        return [("cases", f"{sorted(ra.keys() ^ rb.keys())} in one file only")]
    for key in ra:
        x, y = ra[key], rb[key]
        if key.startswith("/"):
            if not _same(x, y):
                found.append((key, "differs"))
            continue
        if x.keys() != y.keys():
            found.append((key, f"datasets {sorted(x.keys() ^ y.keys())} in one file only"))
            continue
        found += [(f"{key}/{name}", "differs") for name in x if not _same(x[name], y[name])]
    return found


def _same(x, y) -> bool:
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_same(x[k], y[k]) for k in x)
    x, y = np.asarray(x), np.asarray(y)
    if x.dtype.kind in "fc":
        return x.shape == y.shape and np.array_equal(x, y, equal_nan=True)
    return x.shape == y.shape and np.array_equal(x, y)


def assert_same_results(a, b, attrs=True):
    found = differences(a, b, attrs)
    assert not found, found[:10]


#: ten steps of N = 16, the rest of a study file after its [campaign] header: many short cases
TEN_STEPS = """t_end = 0.01
[numerics]
N = 16
dt = 1e-3
[run]
max_spectral_tail = 1.0
sample_interval = 0.001
snapshot_interval = 0.005
checkpoint_interval = 0.005
"""

#: a short case (N = 32, psi_bar = 0.3, S = 80) with ``{t_end}`` and ``{checkpoint}`` to fill in
SHORT = """
[physics]
shear_rate = 80.0
psi_bar = 0.3
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast): the resolution watch would stop it
t_end = {t_end}
sample_interval = 0.005
snapshot_interval = 0.05
checkpoint_interval = {checkpoint}
"""


def run_in_process(case, path, max_steps=None):
    """Run ``case`` into a new case file at ``path`` with hpcves.run.runner (no subprocess); the outcome."""
    from hpcves.run import runner
    from hpcves.run.store import CaseStore, open_file

    with open_file(path, "w-") as f:
        return runner.run(CaseStore.create(f, case), f.flush, max_steps=max_steps)


def resume_in_process(path, stops=(None,), before=None):
    """Resume the case file at ``path`` once per entry of ``stops`` (max_steps of that call, None: to
    the end); ``before(store)`` is called on each opened store first (a check). The last outcome."""
    from hpcves.run import runner
    from hpcves.run.store import CaseStore, open_file

    outcome = None
    for max_steps in stops:
        with open_file(path, "r+") as f:
            store = CaseStore.open(f)
            if before is not None:
                before(store)
            outcome = runner.run(store, f.flush, resume=True, max_steps=max_steps)
    return outcome


#: a case whose N grows once on its way: 24 nodes at the start, 48 from t = 0.01 (step ~1040)
GROWING = """
[physics]
psi_bar = 0.3
shear_rate = 10.0
[numerics]
N = "auto"
N_min = 16
N_max = 64
resize_tail = 2e-2
rtol = 1e-3
[run]
t_end = {t_end}
sample_interval = 0.01
snapshot_interval = 0.05
checkpoint_interval = 0.02
max_spectral_tail = 0.05
"""


def history(path):
    """[(t, N)] at each change of N in a case file's samples, from the first."""
    with h5py.File(path, "r") as f:
        n = int(f["timeseries/length"][()])
        t, N = f["timeseries/t"][:n], f["timeseries/N"][:n]
    return [(float(t[i]), int(N[i])) for i in np.r_[0, np.nonzero(np.diff(N))[0] + 1]]


def same_case_files(a, b, checkpoints=False):
    """Every time series and snapshot of two case files is equal bit for bit (NaN = NaN), their
    checksums too where both formats have them (``b`` may be of a format before the rheology series:
    the series it has, and their checksums, the first of ``a``'s); with ``checkpoints``, the newest
    checkpoints too."""
    from hpcves.run.diagnostics import RHEOLOGY_SERIES
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        for group in ("timeseries", "snapshots"):
            for name in fa[group]:
                if name not in fb[group] and (name == "digest" or name in RHEOLOGY_SERIES):
                    continue
                kept = fb[group][name][()]
                whole = fa[group][name][()][:len(kept)] if name == "digest" else fa[group][name][()]
                assert np.array_equal(whole, kept, equal_nan=True), (group, name)
        if checkpoints:
            newest = [max(("slot0", "slot1"), key=lambda s: f[f"checkpoint/{s}/meta"][1]) for f in (fa, fb)]
            for name in fa[f"checkpoint/{newest[0]}"]:
                if name == "digest" and name not in fb[f"checkpoint/{newest[1]}"]:
                    continue
                assert np.array_equal(fa[f"checkpoint/{newest[0]}/{name}"][()],
                                      fb[f"checkpoint/{newest[1]}/{name}"][()], equal_nan=True), name


def case_store(f, case_id):
    """The CaseStore of case ``case_id`` of an open campaign file (either layout)."""
    from hpcves.campaign.file import CampaignFile

    return CampaignFile(f).store(case_id)
