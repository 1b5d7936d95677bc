"""bench/bench_relay.py runs the relay's own code in one process: it keeps working as that code changes."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_relay  # noqa: E402


def test_the_loopback_relay_runs_tiny_cases_and_times_rank_0(tmp_path):
    row = bench_relay.run(3, tmp_path)
    assert row["cases"] == 3
    assert 0 < row["rank0_ms"] < row["worker_ms"]
    # a fresh case gets its config with its task (no read) and sends its writes in batches
    assert "read config" not in row["messages_per_case"] and row["messages_per_case"]["writes"] >= 2
    assert set(row["by_kind_ms"]) >= {"receive", "writes", "task"}
