"""The loop's event log: queued in the tick, written in the slack, bounded, rate-limited."""

from __future__ import annotations

from typing import Any

from rakectl.daemon.events import LOG_EVERY_S, QUEUE_LENGTH, EventLog


class Captured:
    def __init__(self) -> None:
        self.lines: list[tuple[str, dict[str, Any]]] = []

        self.levels: list[tuple[str, str]] = []

    def info(self, name: str, **fields: Any) -> None:
        self.lines.append((name, fields))
        self.levels.append(("info", name))

    def warning(self, name: str, **fields: Any) -> None:
        self.lines.append((name, fields))
        self.levels.append(("warning", name))

    def error(self, name: str, **fields: Any) -> None:
        self.lines.append((name, fields))
        self.levels.append(("error", name))


def test_events_are_written_in_order_with_the_state_and_only_when_flushed() -> None:
    log = Captured()
    events = EventLog(log)
    events.add("a", {"x": 1})
    events.add("b", {})
    assert log.lines == [] and len(events) == 2
    events.flush("ARMED", 1)
    assert log.lines == [("a", {"state": "ARMED", "x": 1})]
    events.flush("HOLD")
    assert log.lines[-1] == ("b", {"state": "HOLD"}) and len(events) == 0


def test_rate_limited_events_are_written_at_most_once_per_interval() -> None:
    log, now = Captured(), [0.0]
    events = EventLog(log, rate_limited=("timing",), clock_s=lambda: now[0])
    for t_s in (0.0, 0.5 * LOG_EVERY_S, 1.01 * LOG_EVERY_S):
        now[0] = t_s
        events.add("timing", {})
        events.add("state", {})
        events.flush("ARMED")
    assert [name for name, _ in log.lines] == ["timing", "state", "state", "timing", "state"]


def test_the_queue_is_bounded_and_keeps_the_newest() -> None:
    log = Captured()
    events = EventLog(log)
    for i in range(QUEUE_LENGTH + 10):
        events.add("e", {"i": i})
    events.flush("INIT")
    assert len(log.lines) == QUEUE_LENGTH
    assert log.lines[0][1]["i"] == 10


def test_faults_are_errors_and_refusals_warnings() -> None:
    log = Captured()
    events = EventLog(log)
    for name, fields in (("state", {"new": "ARMED"}), ("state", {"new": "FAULT"}),
                         ("state", {"new": "ESTOP"}), ("arm_refused", {"reason": "late"}),
                         ("recorder_dump_failed", {}), ("weight_check", {"passed": False}),
                         ("weight_check", {"passed": True}), ("drives_enabled", {})):
        events.add(name, fields)
    events.flush("X")
    assert [level for level, _ in log.levels] == [
        "info", "error", "error", "warning", "warning", "error", "info", "info"]
