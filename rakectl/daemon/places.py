"""Where the daemon writes: its flight-recorder dumps (``daemon.dump_dir``) and its bus
trace with the trace's inputs (``bus.trace_path``).

:func:`check_places` judges them without touching anything (``rakectl run --check``);
the daemon then makes the dump directory and keeps earlier runs' traces
(:func:`keep_earlier_traces`) before it opens the bus, so that a place it cannot write
is refused, naming its setting, before the drives are touched. Root may write where
the service's user may not: run as root, the check judges as that user
(:func:`service_user`, :func:`judged_as`). A trace is worth most
after a failure, which is when systemd restarts the service: each start moves the
last run's trace and inputs to ``TRACE.1`` (``TRACE.1.inputs.jsonl``), the one before
to ``TRACE.2`` …, up to ``bus.trace_keep`` of them; a start that failed before its
loop ran is not kept.
"""

from __future__ import annotations

import json
import os
import pwd
from collections.abc import Callable
from pathlib import Path

from rakectl.config.settings import Settings
from rakectl.daemon.inputs import sidecar_path
from rakectl.errors import ConfigError

SERVICE_USER = "rakectl"  # the unit's User= (systemd/rakectl.service, rakectl.sysusers)


def dump_dir_of(settings: Settings) -> Path:
    """``daemon.dump_dir``, else systemd's ``$STATE_DIRECTORY``, else the working directory."""
    configured = settings.daemon.dump_dir or os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(configured) if configured else Path.cwd()


def _nearest_existing(path: Path, setting: str) -> Path:
    """``path`` (absolute) or its nearest ancestor that exists; ConfigError naming
    ``setting`` where the way there cannot be followed."""
    blocked = False  # a directory on the way is not searchable: named once it is found
    for place in (path, *path.parents):
        try:
            os.stat(place)
        except PermissionError:
            blocked = True
            continue
        except (FileNotFoundError, NotADirectoryError):
            if os.path.islink(place):  # it would not be made: the name is taken
                raise ConfigError(f"{setting}: {path}: {place} is a symbolic link to "
                                  f"{os.readlink(place)}, which does not exist") from None
            continue
        except OSError as error:  # a symbolic link's loop, a name too long …
            raise ConfigError(f"{setting}: {path}: {error.strerror or error}") from None
        if blocked:
            raise ConfigError(f"{setting}: {path}: {place} is not searchable by {_me()}")
        return place
    raise ConfigError(f"{setting}: {path}: / cannot be read by {_me()}")


def check_directory(path: Path, setting: str) -> None:
    """ConfigError naming ``setting`` unless ``path`` is a directory this process may write
    in, or one it may make (its nearest existing ancestor a directory it may write in)."""
    path = Path(os.path.abspath(path))  # a relative one from the working directory
    place = _nearest_existing(path, setting)
    if not place.is_dir():
        raise ConfigError(f"{setting}: {path}: {place} is not a directory")
    if os.statvfs(place).f_flag & os.ST_RDONLY:
        raise ConfigError(f"{setting}: {path}: {place} is on a read-only filesystem")
    if not os.access(place, os.W_OK | os.X_OK):
        verb = "write in" if place == path else f"make {path} in"
        raise ConfigError(f"{setting}: cannot {verb} {place} (not writable by {_me()})")


def check_file(path: Path, setting: str) -> None:
    """ConfigError naming ``setting`` unless ``path`` is a file this process may write, or
    one it may make."""
    path = Path(os.path.abspath(path))  # a relative one from the working directory
    if os.path.islink(path) and not os.path.exists(path):  # opened, it makes its target
        path = Path(os.path.realpath(path))
    if _nearest_existing(path, setting) == path:
        if path.is_dir():
            raise ConfigError(f"{setting}: {path} is a directory")
        if not os.access(path, os.W_OK):
            raise ConfigError(f"{setting}: cannot write {path} (not writable by {_me()})")
    check_directory(path.parent, setting)


def check_readable(path: Path, what: str) -> None:
    """ConfigError naming ``what`` unless this process may read the file ``path``."""
    _nearest_existing(Path(os.path.abspath(path)), what)
    if not os.access(path, os.R_OK):
        raise ConfigError(f"{what}: cannot read {path} (not readable by {_me()})")


def _me() -> str:
    uid = os.geteuid()
    try:
        return f"{pwd.getpwuid(uid).pw_name} (uid {uid})"
    except KeyError:
        return f"uid {uid}"


def service_user(name: str | None) -> pwd.struct_passwd | None:
    """Whom ``run --check`` judges as: the user ``name``; else, run as root, the service's
    user where it exists (root may write and read where the service cannot); else None,
    this process. ConfigError if ``name`` is no user here."""
    if name is not None:
        try:
            return pwd.getpwnam(name)
        except KeyError:
            raise ConfigError(f"run --check --user: no user {name!r} on this machine") from None
    if os.geteuid() != 0:
        return None
    try:
        return pwd.getpwnam(SERVICE_USER)
    except KeyError:
        return None


def judged_as(user: pwd.struct_passwd, judge: Callable[[], list[str]]) -> list[str]:
    """``judge()`` run in a child process with ``user``'s uid, gid and groups, so that the
    kernel decides what it may read and write (its modes, ACLs and groups), as it will for
    the service: its lines, or the ConfigError it raised, raised here. Judging as another
    user takes root."""
    if user.pw_uid == os.geteuid():
        return judge()
    if os.geteuid() != 0:
        raise ConfigError(f"run --check --user: judging as {user.pw_name} takes root "
                          f"(this is uid {os.geteuid()})")
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover (the child: its coverage is not collected)
        status = 1
        try:
            os.close(read)
            verdict: dict[str, object]
            try:
                os.initgroups(user.pw_name, user.pw_gid)
                os.setgid(user.pw_gid)
                os.setuid(user.pw_uid)
                verdict = {"lines": judge()}
            except ConfigError as error:
                verdict = {"error": str(error)}
            except BaseException as error:  # what the judging itself met, named
                verdict = {"error": f"run --check as {user.pw_name}: {type(error).__name__}: "
                                    f"{error}"}
            with os.fdopen(write, "w") as out:
                json.dump(verdict, out)
            status = 0
        finally:
            os._exit(status)
    os.close(write)
    with os.fdopen(read) as answer:
        text = answer.read()
    _, status = os.waitpid(pid, 0)
    if status or not text:
        code = os.waitstatus_to_exitcode(status)
        ended = f"exited with {code}" if code >= 0 else f"was killed by signal {-code}"
        raise ConfigError(f"run --check: judging as {user.pw_name} failed (its child {ended})")
    reply = json.loads(text)
    if "error" in reply:
        raise ConfigError(str(reply["error"]))
    return [str(line) for line in reply["lines"]]


def places_of(settings: Settings, base: Path | None = None) -> list[tuple[str, Path]]:
    """Where the daemon writes, each with its setting: the dump directory where one is
    given (else the service's StateDirectory), the bus trace, its inputs and the earlier
    runs' kept. A relative one is taken from ``base``, the daemon's working directory
    (by default this process's: the service's is its unit's, :mod:`rakectl.daemon.sandbox`)."""
    places = []
    if settings.daemon.dump_dir or os.environ.get("STATE_DIRECTORY"):
        places.append(("daemon.dump_dir", dump_dir_of(settings)))
    trace = settings.bus.trace_path
    if trace:
        places += [("bus.trace_path", path) for path in
                   (Path(trace), sidecar_path(trace), *_earlier(trace, settings))]
    start = base or Path.cwd()
    return [(setting, Path(os.path.normpath(start / path))) for setting, path in places]


def relative_places(settings: Settings) -> list[tuple[str, str]]:
    """The configured places given relative, each with its setting: the daemon takes them
    from its working directory, which for the service is not the one a person asks from."""
    given = (("daemon.dump_dir", settings.daemon.dump_dir), ("bus.trace_path",
                                                             settings.bus.trace_path))
    return [(setting, value) for setting, value in given
            if value and not os.path.isabs(value)]


def check_places(settings: Settings, base: Path | None = None) -> list[str]:
    """What the daemon would refuse of where it writes (:func:`places_of`, a relative place
    taken from ``base``), judged without touching anything as this process (the unit's
    sandbox is judged apart: :mod:`rakectl.daemon.sandbox`); what was judged, as lines for
    a person. An empty ``daemon.dump_dir`` outside systemd is not judged: the service
    writes to its StateDirectory, not to the working directory of the one asking."""
    places = places_of(settings, base)
    for setting, path in places:
        (check_directory if setting == "daemon.dump_dir" else check_file)(path, setting)
    dump_dirs = [path for setting, path in places if setting == "daemon.dump_dir"]
    lines = [f"dumps to {dump_dirs[0]}" if dump_dirs else "dumps to the service's "
             "StateDirectory (not checked here: daemon.dump_dir is empty)"]
    traces = [path for setting, path in places if setting == "bus.trace_path"]
    if traces:
        lines.append(f"bus trace {traces[0]}, the last {settings.bus.trace_keep} runs' kept")
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
