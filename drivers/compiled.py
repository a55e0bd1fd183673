"""The emulator's physics compiled to C with mypyc: the same code and results, faster.

The substep of the arm, its tine mount, the soil and the buried objects
(``PHYSICS``) is plain scalar Python run 20 000 times a simulated second; mypyc
compiles those modules, as they are, into C extensions (a campaign case then takes
2.9–3.4× less CPU: bench/BENCHMARKS.md section (f)). The arithmetic is the
same IEEE double arithmetic in the same order, so a compiled emulator gives the
same results as the Python one, to the last bit (tests/drivers/test_compiled.py runs
campaign cases both ways and compares them exactly).

A build is kept in a cache directory named by a digest of every source file the
physics may depend on (the drivers package and what tests/test_layering.py lets
it import): a build is used only by the very sources it was made from, so an
edited emulator falls back to Python until it is built again, never runs stale.
Which one runs is decided once, when the ``drivers`` package is imported
(:func:`activate`), by ``RAKECTL_PHYSICS``:

* ``auto`` (default): the compiled physics if a build for these sources exists;
* ``pure``: Python, always;
* ``compiled``: the compiled physics, or an error saying how to build it.

``rakectl compile`` (or :func:`build`) makes the build: mypy (which ships mypyc),
setuptools and a C compiler with the Python headers; the ``[fast]`` extra has the
Python parts. The cache is under ``$XDG_CACHE_HOME/rakectl/physics`` (default
``~/.cache``), or ``RAKECTL_PHYSICS_CACHE``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from rakectl.errors import ConfigError, RakeError

PHYSICS = ("drivers.arm", "drivers.mount", "drivers.mount_sideways", "drivers.mount_vertical",
           "drivers.objects", "drivers.ground", "drivers.soil", "drivers.motor")
GROUP = "rakectl_physics"  # mypyc's shared library: rakectl_physics__mypyc
MODE_ENV, CACHE_ENV = "RAKECTL_PHYSICS", "RAKECTL_PHYSICS_CACHE"
MODES = ("auto", "pure", "compiled")

_PACKAGE = Path(__file__).resolve().parent
_SOURCE_ROOT = _PACKAGE.parent
# what the physics may import (tests/test_layering.py: the "drivers" row); mypyc may
# fold another module's constants into the compiled code, so all of them count
_DEPENDS = ("drivers", "rakectl/config", "rakectl/core", "rakectl/protocol",
            "rakectl/errors.py", "rakectl/limits.py")

_active: Path | None = None


def _sources(root: Path) -> Iterable[Path]:
    for name in _DEPENDS:
        path = root / name
        yield from sorted(path.rglob("*.py")) if path.is_dir() else [path]


def digest(root: Path = _SOURCE_ROOT) -> str:
    """The build's name: the Python ABI and every source file the physics depends on."""
    h = hashlib.sha256(str(sysconfig.get_config_var("EXT_SUFFIX")).encode())
    for path in _sources(root):
        h.update(path.relative_to(root).as_posix().encode() + b"\0")
        h.update(path.read_bytes() + b"\0")
    return h.hexdigest()[:20]


def cache_root() -> Path:
    if CACHE_ENV in os.environ:
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "rakectl" / "physics"


def build_dir(root: Path = _SOURCE_ROOT) -> Path:
    """Where the build of these sources is (or would be)."""
    return cache_root() / digest(root)


def _mode() -> str:
    mode = os.environ.get(MODE_ENV, "auto")
    if mode not in MODES:
        raise ConfigError(f"{MODE_ENV}={mode!r}: expected one of {', '.join(MODES)}")
    return mode


def activate(package_path: list[str]) -> Path | None:
    """Put the build for these sources, if there is one and it is wanted, ahead of the
    Python modules on the drivers package's path (its ``__path__``, from its
    ``__init__``, before any physics module is imported). Returns the build's directory,
    or None when the physics runs as Python."""
    global _active
    mode = _mode()
    if mode == "pure":
        return None
    where = build_dir()
    if not (where / "drivers").is_dir() or not (where / "lib").is_dir():
        if mode == "compiled":
            raise ConfigError(f"{MODE_ENV}=compiled, but the physics of these sources is "
                              f"not built (no {where}): run `rakectl compile`")
        return None
    # the group's shared library, by its unique name, in a directory of its own: a
    # directory holding a drivers/ on sys.path would be taken for the package by a
    # process that inherits this sys.path (multiprocessing's spawn) before the package
    if str(where / "lib") not in sys.path:
        sys.path.append(str(where / "lib"))
    package_path.insert(0, str(where / "drivers"))
    _active = where
    return where


def running() -> str:
    """Which physics this process runs: ``"compiled"``, ``"python"``, or ``"mixed"`` (some
    modules of each; cannot happen through :func:`activate`)."""
    import importlib

    modules = [importlib.import_module(name) for name in PHYSICS]
    compiled = sum(not str(m.__file__).endswith(".py") for m in modules)
    return "python" if compiled == 0 else "compiled" if compiled == len(modules) else "mixed"


def status() -> str:
    """One line: which physics this process runs, and from where."""
    import importlib

    kind = running()
    if kind == "compiled":
        return f"physics: compiled (mypyc) from {_active}"
    if kind == "mixed":  # said plainly if it ever happens
        modules = [importlib.import_module(name) for name in PHYSICS]
        return "physics: MIXED compiled and Python modules: " + ", ".join(
            f"{m.__name__}={m.__file__}" for m in modules)
    hint = "" if _mode() == "pure" else " (`rakectl compile` makes the campaign faster)"
    return f"physics: Python{hint}"


def build(force: bool = False, progress: Callable[[str], None] = print) -> Path:
    """Compile ``PHYSICS`` for these sources into the cache (a minute of CPU); returns
    the build's directory. Kept if already there (unless ``force``). The build is made
    in a temporary directory and moved into place whole, so a failed or interrupted
    build leaves nothing a process could load."""
    target = build_dir()
    if (target / "drivers").is_dir() and not force:
        progress(f"compile: already built for these sources: {target}")
        return target
    for tool in ("mypy", "setuptools"):
        try:
            __import__(tool)
        except ImportError as e:
            raise RakeError(f"compile: {tool} is not installed (pip install "
                              f"'rakectl[fast]')") from e
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=".build-") as tmp:
        work = Path(tmp)
        paths = [str(_SOURCE_ROOT / (name.replace(".", "/") + ".py")) for name in PHYSICS]
        script = (
            "from setuptools import setup\n"
            "from mypyc.build import mypycify\n"
            f"ext = mypycify({paths!r}, opt_level='3', group_name={GROUP!r}, "
            "target_dir='c')\n"
            "setup(name='rakectl-physics', ext_modules=ext, script_args=['build_ext', "
            "'--build-lib', 'lib', '--build-temp', 'obj'])\n")
        progress(f"compile: mypyc {', '.join(PHYSICS)} (about a minute)")
        log = work / "build.log"
        with log.open("w") as out:
            done = subprocess.run([sys.executable, "-c", script], cwd=work, stdout=out,
                                  stderr=subprocess.STDOUT, env={**os.environ,
                                                                 MODE_ENV: "pure"})
        if done.returncode != 0:
            tail = "".join(log.read_text().splitlines(keepends=True)[-15:])
            raise RakeError(f"compile: the build failed (exit {done.returncode}):\n{tail}")
        staged = work / "staged"
        (staged / "drivers").mkdir(parents=True)
        (staged / "lib").mkdir()
        for lib in (work / "lib").glob(f"{GROUP}__mypyc*"):
            shutil.copy2(lib, staged / "lib")
        for name in PHYSICS:
            module = name.split(".")[1]
            found = list((work / "lib" / "drivers").glob(f"{module}.*"))
            if len(found) != 1:
                raise RakeError(f"compile: no single extension for {name} in the build")
            shutil.copy2(found[0], staged / "drivers")
        if target.exists():
            shutil.rmtree(target)
        staged.rename(target)
    progress(f"compile: built {target}")
    return target
