"""The campaign on a Dask LocalCluster (real worker processes, a real scheduler): the same
results case for case as the local pool, a killed worker's job run again, a resumed
campaign skipping what is done. Slow-ish: each test starts a cluster."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rakectl.errors import ConfigError
from rakectl.sim.campaign import campaign
from rakectl.sim.parallel import (
    DaskExecutor,
    LocalExecutor,
    executor_for,
    physics_status,
    workers_physics,
)
from rakectl.sim.results import RESULTS_FILE

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("dask_offload_thread")]
SEED, FIRST, CASES = 20261125, 40, 4


def _die_once(job: tuple[str, int]) -> int:
    """Kills its worker process the first time it meets a job (a marker file remembers)."""
    marker = Path(job[0]) / f"ran-{job[1]}"
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)  # the worker process dies, as a node that goes away
    return 10 * job[1]


def test_a_local_cluster_gives_the_local_pools_results_case_for_case() -> None:
    local = campaign(CASES, SEED, workers=1, first=FIRST)
    executor = DaskExecutor("local:2")
    try:
        assert "2 worker(s)" in executor.describe()
        dask = campaign(CASES, SEED, first=FIRST, executor=executor)
    finally:
        executor.close()
    assert [r.index for r in dask.results] == list(range(FIRST, FIRST + CASES))
    assert dask.results == local.results  # every field of every case
    assert dask.summary()["by_kind"] == local.summary()["by_kind"]


def test_a_job_whose_worker_dies_is_run_again_elsewhere(tmp_path: Path) -> None:
    executor = DaskExecutor("local:2")
    try:
        results = sorted(executor.map_unordered(_die_once, [(str(tmp_path), k)
                                                            for k in range(3)]))
    finally:
        executor.close()
    assert results == [0, 10, 20]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ran-0", "ran-1", "ran-2"]


def _square(k: int) -> int:
    return k * k


def test_a_result_received_is_no_longer_held_on_the_cluster() -> None:
    """Held, a worker lost later (a node gone, a worker restarted after missing its
    heartbeats) would make the scheduler compute it again."""
    executor = DaskExecutor("local:1")
    try:
        results = executor.map_unordered(_square, [1, 2, 3])
        got = [next(results) for _ in range(3)]  # all of them, the iteration still open
        deadline = time.monotonic() + 20.0
        while executor.held_results() and time.monotonic() < deadline:
            time.sleep(0.05)
        held = executor.held_results()
        results.close()
    finally:
        executor.close()
    assert sorted(got) == [1, 4, 9]
    assert held == 0


def test_a_resumed_campaign_on_the_cluster_runs_only_what_is_missing(tmp_path: Path) -> None:
    first = campaign(2, SEED, workers=1, out_dir=tmp_path, first=FIRST)
    executor = executor_for("local:2", 1)
    try:
        resumed = campaign(CASES, SEED, out_dir=tmp_path, first=FIRST, executor=executor)
    finally:
        executor.close()
    assert resumed.resumed == 2
    assert resumed.results[:2] == first.results
    lines = (tmp_path / RESULTS_FILE).read_text().splitlines()
    assert len(lines) == CASES  # the two done were not run again


def test_the_workers_physics_is_one_line_naming_any_difference() -> None:
    compiled = "physics: compiled (mypyc) from /cache/a"
    python = "physics: Python"
    assert workers_physics({"w1": compiled, "w2": compiled}) == \
        f"{compiled} (on all 2 worker(s))"
    assert workers_physics({"w1": compiled, "w2": python, "w3": python}) == \
        f"workers DIFFER: 2 with {python}; 1 with {compiled}"
    assert workers_physics({}) == "physics: no worker answered"
    assert LocalExecutor(2).physics() == physics_status()  # forked: this process's


@pytest.mark.parametrize("scheduler", ["local:0", "local:x", "udp://h:1", "h:8786"])
def test_a_bad_scheduler_is_refused_naming_it(scheduler: str) -> None:
    with pytest.raises(ConfigError, match="--scheduler"):
        executor_for(scheduler, 1)


def test_the_command_line_runs_on_a_local_cluster_and_refuses_a_bad_scheduler(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rakectl.cli.main import main

    assert main(["fuzz", "--scenarios", "2", "--seed", str(SEED), "--first", str(FIRST),
                 "--scheduler", "local:2", "--out", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert "on Dask local:2 (2 worker(s))" in captured.err
    # what the workers run, asked of them (the test run's cache is empty: Python)
    assert "physics: Python" in captured.err and "(on all 2 worker(s))" in captured.err
    assert "2 scenarios" in captured.out
    assert main(["fuzz", "--scenarios", "2", "--scheduler", "nowhere"]) == 2
    assert "--scheduler 'nowhere'" in capsys.readouterr().err
    # the benchmark names a bad one before its other parts, and only takes one where it
    # has runs to send
    assert main(["bench", "--all", "--quick", "--scheduler", "local:x"]) == 2
    assert "--scheduler local:x: local:N needs N >= 1 workers" in capsys.readouterr().err
    assert main(["bench", "--tick", "--scheduler", "local:2"]) == 2
    assert "--scheduler is for the excavation runs" in capsys.readouterr().err


def test_a_missing_cluster_extra_is_named_before_any_benchmark_runs(tmp_path: Path) -> None:
    """`bench --all --scheduler local:2` without Dask's distributed ran every other part
    (minutes) before the excavation's runs found it missing, and wrote nothing."""
    hidden = tmp_path / "hidden" / "distributed"
    hidden.mkdir(parents=True)
    (hidden / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    report = tmp_path / "report"
    done = subprocess.run([sys.executable, "-m", "rakectl", "bench", "--all", "--quick",
                           "--scheduler", "local:2", "--report", str(report)],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(hidden.parent)})
    assert done.returncode != 0 and done.stdout == ""  # no part ran (each prints)
    assert done.stderr.strip() == ("rakectl: error: --scheduler needs the [cluster] extra: "
                                   "pip install 'rakectl[cluster]' (hidden by the test)")
    assert not report.exists()
