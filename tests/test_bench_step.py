"""bench/bench_step.py times the solver of any tree in a child process: it keeps working as the code changes."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import bench_step  # noqa: E402


def test_the_step_benchmark_times_a_tree_against_itself():
    rows = bench_step.compare(ROOT, ROOT, [32], ["two-phase"], rounds=1, blocks=1, seconds=0.02)
    assert len(rows) == 1 and rows[0]["N"] == 32
    assert rows[0]["base_ms"] > 0 and rows[0]["new_ms"] > 0 and 0.1 < rows[0]["ratio"] < 10
