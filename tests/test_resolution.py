"""The resolution watch: the spectral tail of theta and psi in every sample; under-resolved runs stop."""
import h5py
import numpy as np
import pytest

from hpcves.config import case_from_toml
from hpcves.numerics.spectral import resolution_needed, spectral_tail
from hpcves.run.store import FAILED, FINISHED
from jobs import run_in_process


def decaying(N, kappa):
    m = np.arange(N // 2 + 1)
    return np.where(m > 0, np.exp(-kappa * m), 0.0)


def test_the_tail_is_the_share_of_the_top_third_of_the_modes():
    N = 64
    assert spectral_tail(np.zeros(N // 2 + 1), N) == 0.0
    f = np.zeros(N // 2 + 1)
    f[3] = 1.0
    assert spectral_tail(f, N) == 0.0               # a low mode alone: nothing in the top third
    f[25] = 1.0
    assert spectral_tail(f, N) == pytest.approx(np.sqrt(0.5))
    assert spectral_tail(decaying(N, 0.3), N) == pytest.approx(np.exp(-0.3 * 21), rel=0.05)


def test_the_resolution_needed_brings_the_tail_to_its_target():
    N = 48
    for kappa in (0.2, 0.3, 0.6):
        needed = resolution_needed(decaying(N, kappa), N, 1e-6)
        assert needed % 16 == 0 and needed > N
        assert spectral_tail(decaying(needed, kappa), needed) <= 1e-6
        assert spectral_tail(decaying(needed - 16, kappa), needed - 16) > 1e-6     # and not more than needed
    assert resolution_needed(decaying(N, 0.1), N, 1e-6) == 8 * N                  # beyond 8 N: says 8 N
    assert resolution_needed(np.ones(N // 2 + 1), N, 1e-6) == 2 * N              # no decay to extrapolate


CASE = """
[physics]
shear_rate = 80.0
psi_bar = 0.3
[numerics]
N = {N}
rtol = 1e-2
[run]
t_end = 0.3
sample_interval = 0.005
snapshot_interval = 0.1
"""


def test_a_field_with_a_heavy_tail_stops_the_run_as_under_resolved_naming_the_N_it_needs(tmp_path):
    outcome = run_in_process(case_from_toml(CASE.format(N=32)), tmp_path / "coarse.h5")
    assert outcome.status == FAILED and outcome.message.startswith("under-resolved:"), outcome.message
    needed = int(outcome.message.split("N = ")[-1].split()[0])
    assert needed >= 48, outcome.message
    assert "diverged" not in outcome.message
    # at rtol = 1e-2 a growing tail may be the step's doing: the message says what to try first
    assert "unless the step lets grid-scale error grow: at numerics.rtol = 0.01 try rtol = 0.001" in outcome.message


def test_the_loose_step_hint_is_given_only_where_the_step_tolerance_is_loose():
    from hpcves.run.diagnostics import _loose_step_hint

    def numerics(extra):
        return case_from_toml(CASE.format(N=32).replace("rtol = 1e-2", extra)).numerics

    assert _loose_step_hint(numerics("rtol = 1e-2")).startswith(", unless the step")
    assert _loose_step_hint(numerics("rtol = 1e-3")) == ""
    assert _loose_step_hint(numerics("dt = 1e-4")) == ""             # a fixed step: nothing to loosen


def test_a_resolved_run_records_small_tails_that_fall_with_N(tmp_path):
    tails = {}
    for N in (64, 128):
        outcome = run_in_process(case_from_toml(CASE.format(N=N)), tmp_path / f"n{N}.h5")
        assert outcome.status == FINISHED, outcome.message
        with h5py.File(tmp_path / f"n{N}.h5", "r") as f:
            n = int(f["timeseries/length"][()])
            tails[N] = (f["timeseries/tail_theta"][:n].max(), f["timeseries/tail_psi"][:n].max())
    assert max(tails[64]) < 1e-3
    assert tails[128][0] < tails[64][0] / 10 and tails[128][1] < tails[64][1] / 10, tails
