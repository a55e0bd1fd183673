"""Progress lines: silent for short work, then periodic, always ending at 100 %."""

from __future__ import annotations

import io

from rakectl.sim.progress import Progress


def test_short_work_prints_nothing() -> None:
    stream = io.StringIO()
    progress = Progress("job", stream=stream, quiet_s=60.0)
    for done in range(0, 11):
        progress(done, 10)
    assert stream.getvalue() == ""


def test_long_work_prints_lines_and_finishes() -> None:
    stream = io.StringIO()
    progress = Progress("job", stream=stream, quiet_s=0.0, every_s=0.0)
    for done in range(0, 11):
        progress(done, 10)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("job:   0.0% (0/10)")
    assert lines[-1].startswith("job: 100.0% (10/10)")
    assert len(lines) == 11


def test_the_time_left_of_a_resumed_run_is_judged_by_its_own_pace() -> None:
    """18 of 20 read back from an earlier run, then one case in 2 s: about 2 s left,
    not the 0.1 s that counting the 18 as this run's work gave."""
    now = [0.0]
    stream = io.StringIO()
    progress = Progress("fuzz", stream=stream, quiet_s=0.0, every_s=0.0, clock=lambda: now[0])
    progress.skip(18)
    progress(18, 20)
    now[0] = 2.0
    progress(19, 20)
    assert stream.getvalue().splitlines()[-1] == "fuzz:  95.0% (19/20), 2 s, ~2 s left"
