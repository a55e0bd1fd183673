"""Where the daemon writes: its flight-recorder dumps (``daemon.dump_dir``) and its bus
trace with the trace's inputs (``bus.trace_path``).

:func:`check_places` judges them without touching anything (``rakectl run --check``);
the daemon then makes the dump directory and keeps earlier runs' traces
(:func:`keep_earlier_traces`) before it opens the bus, so that a place it cannot write
is refused, naming its setting, before the drives are touched. A trace is worth most
after a failure, which is when systemd restarts the service: each start moves the
last run's trace and inputs to ``TRACE.1`` (``TRACE.1.inputs.jsonl``), the one before
to ``TRACE.2`` …, up to ``bus.trace_keep`` of them; a start that failed before its
loop ran is not kept.
"""

from __future__ import annotations

import os
from pathlib import Path

from rakectl.config.settings import Settings
from rakectl.daemon.inputs import sidecar_path
from rakectl.errors import ConfigError


def dump_dir_of(settings: Settings) -> Path:
    """``daemon.dump_dir``, else systemd's ``$STATE_DIRECTORY``, else the working directory."""
    configured = settings.daemon.dump_dir or os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(configured) if configured else Path.cwd()


def _nearest_existing(path: Path) -> Path:
    for place in (path, *path.parents):
        if place.exists():
            return place
    return Path("/")  # pragma: no cover (the root exists)


def check_directory(path: Path, setting: str) -> None:
    """ConfigError naming ``setting`` unless ``path`` is a directory this process may write
    in, or one it may make (its nearest existing ancestor a directory it may write in)."""
    place = _nearest_existing(path)
    if not place.is_dir():
        raise ConfigError(f"{setting}: {path}: {place} is not a directory")
    if os.statvfs(place).f_flag & os.ST_RDONLY:
        raise ConfigError(f"{setting}: {path}: {place} is on a read-only filesystem")
    if not os.access(place, os.W_OK | os.X_OK):
        verb = "write in" if place == path else f"make {path} in"
        raise ConfigError(f"{setting}: cannot {verb} {place} (not writable by uid "
                          f"{os.geteuid()})")


def check_file(path: Path, setting: str) -> None:
    """ConfigError naming ``setting`` unless ``path`` is a file this process may write, or
    one it may make."""
    if path.is_dir():
        raise ConfigError(f"{setting}: {path} is a directory")
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"{setting}: cannot write {path} (not writable by uid "
                          f"{os.geteuid()})")
    check_directory(path.parent, setting)


def check_places(settings: Settings) -> list[str]:
    """What the daemon would refuse of where it writes, judged without touching anything
    as this process (a filesystem read-only in the service's sandbox alone is not seen
    from outside it); what was judged, as lines for a person. An empty
    ``daemon.dump_dir`` outside systemd is not judged: the service writes to its
    StateDirectory, not to the working directory of the one asking."""
    if settings.daemon.dump_dir or os.environ.get("STATE_DIRECTORY"):
        dump_dir = dump_dir_of(settings)
        check_directory(dump_dir, "daemon.dump_dir")
        lines = [f"dumps to {dump_dir}"]
    else:
        lines = ["dumps to the service's StateDirectory (not checked here: daemon.dump_dir "
                 "is empty)"]
    trace = settings.bus.trace_path
    if trace:
        for path in (Path(trace), sidecar_path(trace), *_earlier(trace, settings)):
            check_file(path, "bus.trace_path")
        lines.append(f"bus trace {trace}, the last {settings.bus.trace_keep} runs' kept")
    return lines


def make_dump_dir(settings: Settings) -> Path:
    """The dump directory, made if it is not there; ConfigError naming ``daemon.dump_dir``."""
    path = dump_dir_of(settings)
    check_directory(path, "daemon.dump_dir")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"daemon.dump_dir: cannot make {path}: "
                          f"{error.strerror or error}") from None
    return path


def _earlier(trace: str, settings: Settings) -> list[Path]:
    return [Path(f"{trace}.{n}") for n in range(1, settings.bus.trace_keep + 1)]


def _beyond(trace: str, keep: int) -> list[Path]:
    """Earlier runs' traces numbered past ``keep`` (``trace_keep`` lowered since), and
    their inputs."""
    found = []
    for path in Path(trace).parent.glob(f"{Path(trace).name}.*"):
        number = path.name[len(Path(trace).name) + 1:].removesuffix(".inputs.jsonl")
        if number.isdigit() and int(number) > keep:
            found.append(path)
    return found


def keep_earlier_traces(settings: Settings) -> list[Path]:
    """Make the trace's directory if it is not there; move the last run's trace and
    inputs to ``TRACE.1`` (and its inputs), shifting those before up to
    ``bus.trace_keep`` (older ones removed). Only a run whose loop ran is kept, its
    inputs holding their start entry: a start that failed before (drives absent, the
    link down, each restart systemd makes) is overwritten by the next and never pushes
    an incident's trace out. With ``trace_keep`` 0 nothing is kept. Returns the files
    moved to, newest first. ConfigError naming ``bus.trace_path`` if they cannot be made
    or moved."""
    trace = settings.bus.trace_path
    if not trace:
        return []
    current, keep = Path(trace), settings.bus.trace_keep
    try:
        current.parent.mkdir(parents=True, exist_ok=True)
        for path in _beyond(trace, keep):
            path.unlink(missing_ok=True)
        inputs = sidecar_path(trace)
        if not keep or not inputs.is_file() or inputs.stat().st_size == 0:
            return []
        chain = [current, *_earlier(trace, settings)]
        for path in (chain[-1], sidecar_path(chain[-1])):
            path.unlink(missing_ok=True)
        for older, newer in reversed(list(zip(chain[1:], chain[:-1], strict=True))):
            for source, target in ((newer, older), (sidecar_path(newer), sidecar_path(older))):
                if source.exists():
                    source.replace(target)
    except OSError as error:
        raise ConfigError(f"bus.trace_path: cannot keep the last run's trace {trace}: "
                          f"{error.strerror or error}") from None
    kept = []  # each run kept, by its trace (or its inputs, where the trace is gone)
    for older in chain[1:]:
        found = [path for path in (older, sidecar_path(older)) if path.exists()]
        kept += found[:1]
    return kept
