"""``rakectl run``: the daemon's composition root.

The only place that reads the configuration and the environment, opens the
CAN bus, installs signal handlers, sets up real time and talks to systemd.
SIGTERM, SIGINT and SIGHUP only record the request once the drives are up; the loop
ends its tick, sends 0 V with the drives disabled, dumps the flight recorder and
returns 0. Before (cyclictest, the drives' bring-up, nothing enabled yet) a stop ends
the start-up where it is, status 0. Before the bus is opened the daemon checks its
command socket (``check_endpoint``), refuses one a daemon listens on and claims it
(``claim``: ``<socket>.lock``, held until the process ends), and a CAN link running at
another bit rate than ``bus.bitrate`` is refused (:mod:`rakectl.drive.link`).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import structlog

from rakectl.api.client import socket_path
from rakectl.api.endpoint import check_endpoint, claim, refuse_if_listening
from rakectl.api.server import CommandServer
from rakectl.config.loader import load_settings
from rakectl.config.service import DaemonSettings
from rakectl.config.settings import Settings, held_command_gap
from rakectl.daemon.cyclictest import run_cyclictest
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.inputs import InputLog, open_inputs
from rakectl.daemon.loop import Daemon
from rakectl.daemon.places import keep_earlier_traces, make_dump_dir
from rakectl.daemon.rt import RtMode, RtRequest, apply_rt, freeze_gc
from rakectl.daemon.sdnotify import Notifier
from rakectl.drive.bringup import CONFIGURE_ATTEMPTS
from rakectl.drive.canbus import TraceRecorder, open_bus, open_trace
from rakectl.drive.client import DriveClient
from rakectl.drive.joints import receive_ids
from rakectl.drive.link import check_link_bitrate


def configure_logging() -> None:
    """structlog: JSON lines when stderr is not a terminal (journald), readable on one."""
    renderer: structlog.typing.Processor = (
        structlog.dev.ConsoleRenderer() if sys.stderr.isatty()
        else structlog.processors.JSONRenderer())
    structlog.configure(
        processors=[structlog.processors.add_log_level,
                    structlog.processors.TimeStamper(fmt="iso", utc=True), renderer],
        wrapper_class=structlog.make_filtering_bound_logger(logging.INFO),
        logger_factory=structlog.PrintLoggerFactory(sys.stderr),
        cache_logger_on_first_use=True,
    )


class _StopDuringStartUp(Exception):  # a stop asked, not an error
    """SIGTERM, SIGINT or SIGHUP before the loop runs (the drives' bring-up waiting for
    drives that do not answer, cyclictest): the start-up ends there, exit status 0."""


def _rt_request(settings: Settings) -> RtRequest:
    d = settings.daemon
    return RtRequest(priority=d.rt_priority, cpus=frozenset({d.cpu}) if d.cpu >= 0 else None)


# added to each start-up phase's own bound: the process's work around it (an SDO
# transfer's timeouts, cyclictest's start), a machine under load
START_PHASE_MARGIN_S = 30.0


# the bring-up's waits of up to daemon.boot_timeout_s each, one after another: each
# drive's boot-up after a reset (again from the reset if it restarts, CONFIGURE_ATTEMPTS
# times), each drive's heartbeat saying OPERATIONAL after NMT start, and the loop's first
# valid feedback from both
BRING_UP_WAITS = 2 * CONFIGURE_ATTEMPTS + 2 + 1


def bring_up_bound_s(daemon: DaemonSettings) -> float:
    """How long bring-up and the loop's first valid feedback may take before READY."""
    return BRING_UP_WAITS * daemon.boot_timeout_s + START_PHASE_MARGIN_S


def measure_reference(daemon: DaemonSettings, notifier: Notifier) -> dict[str, Any]:
    """cyclictest's wake-up latency for ``daemon.startup_cyclictest_s`` (before bring-up:
    nothing else of the daemon runs yet), or why it is absent."""
    seconds = daemon.startup_cyclictest_s
    if seconds <= 0.0:
        return {"reason": "not measured (daemon.startup_cyclictest_s: 0)"}
    notifier.extend_start(seconds + START_PHASE_MARGIN_S,
                          f"measuring the machine's wake-up latency (cyclictest, {seconds:g} s)")
    reasons: list[str] = []
    result = run_cyclictest(seconds, priority=daemon.rt_priority, why_not=reasons.append)
    if result is None:
        return {"reason": "; ".join(reasons) or "cyclictest failed"}
    latency = result["latency_ns"]
    return {"label": result["label"], "samples": result["samples"],
            "p50_us": latency["p50"] * 1e-3, "p99_us": latency["p99"] * 1e-3,
            "max_us": latency["max"] * 1e-3}


def run(config: Path | None, overrides: list[str]) -> int:
    """Run the daemon until SIGTERM, SIGINT, SIGHUP or the shutdown command; 0 on a clean
    stop."""
    settings = load_settings(config, overrides, root=Settings)
    configure_logging()
    log = structlog.get_logger("rakectl")
    # before the bus: a second daemon's bring-up would reset the first one's drives, and
    # what would refuse the command socket or the dumps must not wait until after it
    path = socket_path(settings.daemon.socket_path or None)
    check_endpoint(path, settings.daemon.socket_group or None)
    bitrate, link = check_link_bitrate(settings.bus)  # at another rate it hears no drive
    log.info("can_link", bitrate=bitrate, link=link)
    refuse_if_listening(path)  # a running daemon, named as such
    claimed = claim(path)  # one starting at the same moment, refused here
    trace: TraceRecorder | None = None
    inputs: InputLog | None = None
    try:
        dump_dir = make_dump_dir(settings)
        kept = keep_earlier_traces(settings)  # the run before, kept for its incident
        trace = open_trace(settings.bus)
        inputs = open_inputs(settings.bus)  # what a replay needs besides the trace
        bus = open_bus(settings.bus, receive_ids(settings.drives))
    except BaseException:
        for recording in (trace, inputs):
            if recording is not None:
                with contextlib.suppress(OSError):
                    recording.close()
        os.close(claimed)
        raise
    if kept:
        log.info("trace_kept", last_run=str(kept[0]), kept=len(kept))
    server: CommandServer | None = None
    try:
        client = DriveClient(bus, settings.drives, settings.motors, settings.rate_hz, trace)
        notifier = Notifier.from_environ(os.environ)
        daemon = Daemon(settings, client, notifier, dump_dir)
        daemon.trace, daemon.inputs = trace, inputs

        starting = [True]  # before the loop, a stop ends the start-up where it is

        def on_signal(signum: int, frame: FrameType | None) -> None:
            daemon.request_stop()
            if starting[0]:
                starting[0] = False
                raise _StopDuringStartUp(signal.Signals(signum).name)

        for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):  # HUP: its terminal
            signal.signal(signum, on_signal)  # closed, as the CLI reads it
        try:
            daemon.timing_reference = measure_reference(settings.daemon, notifier)
            log.info("timing_reference", **daemon.timing_reference)
            notifier.extend_start(bring_up_bound_s(settings.daemon), "bringing up the drives")
            daemon.bring_up()
            starting[0] = False  # from here a stop is the loop's (it stops at its first tick)
        except _StopDuringStartUp as stop:  # the drives were never enabled
            log.info("stopped", during="start-up", signal=str(stop))
            return 0
        report = apply_rt(RtMode(settings.daemon.rt_mode.value), _rt_request(settings))
        for warning in report.warnings:
            log.warning("realtime", problem=warning)
        server = CommandServer(path, settings.daemon.socket_group or None, make_handler(daemon))
        daemon.slack_hook = server.poll
        daemon.connected = server.is_connected
        log.info("started", socket=str(path), rt=str(report.mode.value),
                 bus=f"{settings.bus.interface}:{settings.bus.channel}", priority=report.priority)
        gap = held_command_gap(settings)
        if gap:
            log.warning("clamp_warning", reason=gap)
        freeze_gc()
        gc.disable()  # no collection in the loop: the slack collects young generations
        daemon.run()
    finally:
        gc.enable()
        if server is not None:
            server.close()
        for recording in (trace, inputs):
            if recording is not None:
                try:
                    recording.close()
                except OSError as error:  # a full disk: the trace ends, the stop goes on
                    log.warning("trace_failed", error=f"{type(error).__name__}: {error}")
        with contextlib.suppress(Exception):
            bus.shutdown()
        os.close(claimed)
    log.info("stopped", **{**daemon.timing.summary(), "ticks": daemon.ticks})
    return 0
