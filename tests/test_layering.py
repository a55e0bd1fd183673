"""The import layering holds: which package may import which, checked on the source.

Every ``import`` in rakectl/ and drivers/ (function-level ones included) is
read with ``ast`` and judged against the table below; a forbidden import fails
with the file, the line and the rule.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BASE = ("rakectl.errors", "rakectl.limits")
ALLOWED: dict[str, tuple[str, ...]] = {
    "rakectl": (),  # the package's own __init__, and any subpackage not listed below
    "rakectl.errors": (),
    "rakectl.limits": (),
    # the motor model's declarations; the geometry that checks a configured pose (pure);
    # the drive profiles' names (a leaf: the protocol's data files); the descent budget's
    # derivation that checks the configured soil bound, and the loop's stability that
    # checks the configured impedance (both pure)
    "rakectl.config": (*BASE, "rakectl.config", "rakectl.core.motor_model",
                       "rakectl.core.kinematics", "rakectl.core.descent",
                       "rakectl.core.stability", "rakectl.protocol.files"),
    "rakectl.core": (*BASE, "rakectl.config", "rakectl.core"),
    "rakectl.protocol": (*BASE, "rakectl.protocol"),
    "rakectl.drive": (*BASE, "rakectl.config", "rakectl.core", "rakectl.protocol",
                      "rakectl.drive"),
    "rakectl.api": (*BASE, "rakectl.config", "rakectl.api"),
    "rakectl.daemon": (*BASE, "rakectl.config", "rakectl.core", "rakectl.protocol",
                       "rakectl.drive", "rakectl.api", "rakectl.daemon"),
    "rakectl.sim": (*BASE, "rakectl.config", "rakectl.core", "rakectl.protocol",
                    "rakectl.drive", "rakectl.api", "rakectl.daemon", "rakectl.sim",
                    "rakectl.view", "drivers"),
    "rakectl.bench": (*BASE, "rakectl.config", "rakectl.core", "rakectl.protocol",
                      "rakectl.drive", "rakectl.api", "rakectl.daemon", "rakectl.sim",
                      "rakectl.view", "rakectl.bench", "drivers"),
    "rakectl.view": (*BASE, "rakectl.config", "rakectl.core", "rakectl.api", "rakectl.daemon",
                     "rakectl.view"),
    "rakectl.cli": ("rakectl", "drivers"),
    "rakectl.__main__": ("rakectl.cli",),
    "drivers": (*BASE, "rakectl.config", "rakectl.protocol", "rakectl.core.kinematics",
                "rakectl.core.motor_model", "drivers"),
}
# The pure core: numbers in, numbers out (no I/O, no clock, no logging).
IMPURE = ("can", "canopen", "yaml", "structlog", "time", "socket", "threading", "subprocess")
PURE = ("rakectl.core", "rakectl.protocol.codec", "rakectl.protocol.nmt",
        "rakectl.protocol.cia402", "rakectl.protocol.roboteq")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports(source: str, package: str) -> Iterator[tuple[int, str]]:
    """(line, module) for every import; ``from pkg import mod`` counts as pkg.mod."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            for alias in node.names:
                full = f"{base}.{alias.name}"
                yield node.lineno, full if _is_module(full) else base


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _violations(module: str, source: str, is_package: bool = False) -> list[str]:
    key = max((k for k in ALLOWED if _within(module, (k,))), key=len, default=None)
    assert key is not None, f"{module} belongs to no layer: add it to ALLOWED"
    package = module if is_package else module.rpartition(".")[0]
    return [f"{line}: {key} may not import {name}"
            for line, name in _imports(source, package)
            if _within(name, ("rakectl", "drivers")) and not _within(name, ALLOWED[key])]


def _sources() -> list[Path]:
    return sorted([*ROOT.glob("rakectl/**/*.py"), *ROOT.glob("drivers/**/*.py")])


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("path", _sources(), ids=_id)
def test_imports_follow_the_layers(path: Path) -> None:
    bad = _violations(_module_name(path), path.read_text(), path.name == "__init__.py")
    assert not bad, "\n".join(f"{_id(path)}:{line}" for line in bad)


@pytest.mark.parametrize("path", [p for p in _sources() if _within(_module_name(p), PURE)],
                         ids=_id)
def test_the_pure_core_imports_no_io(path: Path) -> None:
    package = _module_name(path).rpartition(".")[0]
    bad = [f"{_id(path)}:{line}: the pure core may not import {name}"
           for line, name in _imports(path.read_text(), package) if _within(name, IMPURE)]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(("module", "source", "expected"), [
    ("drivers.arm", "from rakectl.daemon.loop import Daemon\n",
     "drivers may not import rakectl.daemon.loop"),
    ("drivers.arm", "def f():\n    from rakectl.sim import rig\n",
     "drivers may not import rakectl.sim.rig"),
    ("rakectl.core.clamp", "from ..drive import client\n",
     "rakectl.core may not import rakectl.drive.client"),
    ("rakectl.config.reference", "import drivers.settings\n",
     "rakectl.config may not import drivers.settings"),
])
def test_a_forbidden_import_is_caught(module: str, source: str, expected: str) -> None:
    assert any(expected in line for line in _violations(module, source))


def test_an_allowed_import_passes() -> None:
    assert not _violations("drivers.arm", "from rakectl.core import kinematics\n")
