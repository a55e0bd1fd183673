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
