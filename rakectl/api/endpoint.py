"""The command socket's file and its peers: where the daemon listens, in a directory
only root or its own user owns, mode 0660 in the socket's group; a stale socket that
nobody listens on is replaced, anything else refused; and who may connect (root, the
daemon's user, the group's members), from the peer's credentials. Before the bus is
opened: :func:`check_endpoint` (what :func:`listen` would refuse) and :func:`claim`
(``<socket>.lock``, against a daemon or a dry run starting at the same moment)."""

from __future__ import annotations

import contextlib
import fcntl
import grp
import os
import pwd
import socket
import stat
import struct
from pathlib import Path

from rakectl.api.schema import Peer
from rakectl.errors import ApiError, ConfigError

_SO_PEERGROUPS = getattr(socket, "SO_PEERGROUPS", 59)  # Linux >= 4.13; 59 in asm-generic


def peer_allowed(peer: Peer, daemon_uid: int, socket_gid: int) -> bool:
    """Root, the daemon's own user, or a member of the socket's group (pure)."""
    return peer.uid in (0, daemon_uid) or peer.gid == socket_gid or socket_gid in peer.groups


def peer_of(sock: socket.socket) -> Peer:
    """The credentials of a connected peer, as the kernel gives them."""
    pid, uid, gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                        struct.calcsize("3i")))
    try:  # the peer process's own groups at connect time, as the kernel saw them
        raw = sock.getsockopt(socket.SOL_SOCKET, _SO_PEERGROUPS, 1024)  # Python: <= 1024
        groups = frozenset(struct.unpack(f"{len(raw) // 4}I", raw))
    except OSError:  # older kernel: the group database
        try:
            groups = frozenset(os.getgrouplist(pwd.getpwuid(uid).pw_name, gid))
        except KeyError:
            groups = frozenset()
    return Peer(pid, uid, gid, groups)


def group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def listen(path: Path, group: str | None, backlog: int) -> socket.socket:
    """A listening socket at ``path``: mode 0660, owned by ``group`` if given."""
    gid = _group_id(group)
    _prepare_directory(path.parent)
    _remove_stale(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(str(path))
        os.chmod(path, 0o660)
        if gid is not None and os.stat(path).st_gid != gid:
            os.chown(path, -1, gid)
        sock.listen(backlog)
        sock.setblocking(False)
    except OSError as exc:
        sock.close()
        with contextlib.suppress(OSError):
            os.unlink(path)
        hint = (f" (the daemon's user must be in group {group})"
                if isinstance(exc, PermissionError) and group else "")
        raise ApiError(f"cannot set up the command socket {path}: "
                       f"{exc.strerror or exc}{hint}") from exc
    return sock


def claim(path: Path) -> int:
    """An exclusive claim on the daemon of the command socket ``path``, before it touches
    the bus: ``flock`` on ``<path>.lock``, held by the returned descriptor until it is
    closed or the process ends however it ends (the kernel releases it). ApiError naming
    the lock if another process holds it: a daemon started moments before this one, whose
    socket does not exist until its bring-up has ended, which this one's bring-up would
    have reset under it."""
    _prepare_directory(path.parent)
    lock = path.with_name(path.name + ".lock")
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    except OSError as exc:
        raise ApiError(f"cannot claim the command socket {path}: {lock}: "
                       f"{exc.strerror or exc}") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise ApiError(f"another daemon is starting or running with the command socket "
                       f"{path} (it holds {lock})") from None
    return fd


SUN_PATH_MAX_BYTES = 107  # an AF_UNIX socket's path: sun_path's 108 bytes, its NUL included


def check_endpoint(path: Path, group: str | None) -> None:
    """What :func:`listen` would refuse, judged without touching anything: a path longer
    than AF_UNIX takes, a group that does not exist (ConfigError naming the setting). The
    daemon asks before the drives' bring-up, and ``rakectl run --check`` too."""
    size = len(os.fsencode(path))
    if size > SUN_PATH_MAX_BYTES:
        raise ConfigError(f"daemon.socket_path: the command socket's path {path} is {size} "
                          f"bytes long; AF_UNIX takes at most {SUN_PATH_MAX_BYTES}")
    try:
        _group_id(group)
    except ApiError as error:
        raise ConfigError(f"daemon.socket_group: {error}") from None


def _group_id(group: str | None) -> int | None:
    if group is None:
        return None
    try:
        return grp.getgrnam(group).gr_gid
    except KeyError:
        raise ApiError(f"the command socket's group {group!r} does not exist (create it with "
                       "systemd-sysusers or groupadd)") from None


def _prepare_directory(directory: Path) -> None:
    try:
        directory.mkdir(mode=0o750, parents=True, exist_ok=True)
        st = os.lstat(directory)
    except OSError as exc:
        raise ApiError(f"cannot create the directory of the command socket {directory}: "
                       f"{exc.strerror or exc}") from exc
    if not stat.S_ISDIR(st.st_mode) or st.st_uid not in (0, os.geteuid()):
        raise ApiError(f"refusing to put the command socket in {directory}: not a directory "
                       f"owned by root or by uid {os.geteuid()}")


def refuse_if_listening(path: Path) -> None:
    """ApiError if another daemon listens at ``path``, or the path is not a socket (a
    stale socket nobody listens on is removed): what a daemon checks before it touches
    the bus, so that a second one never disturbs the drives of the first."""
    _remove_stale(path)


def _remove_stale(path: Path) -> None:
    """Remove a socket file that nobody listens on; refuse anything else."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise ApiError(f"{path} exists and is not a socket; refusing to replace it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(0.5)
    try:
        probe.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return
    except (TimeoutError, BlockingIOError):
        pass  # its backlog is full: somebody listens
    except OSError as exc:
        raise ApiError(f"cannot tell whether {path} is in use: {exc.strerror or exc}") from exc
    finally:
        probe.close()
    raise ApiError(f"another daemon is already listening at {path}")
