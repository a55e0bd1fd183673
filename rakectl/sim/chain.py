"""Which code a campaign's result came from: a digest of the sources a case runs through.

A case's result is a function of its seed and index and of the code that ran it: the
emulator's physics (``drivers``), the controller, clamp and supervision
(``rakectl.core``, ``rakectl.config``) and the runner (``rakectl.sim``). A change to
that code may move any result, so results of two versions are not one campaign's. Each
result records the digest of the code it ran on (``chain``); a campaign refuses to add
results to a directory that holds another version's, a merge refuses to table two
versions together, and a comparison or a replay says when the versions differ
(:mod:`rakectl.sim.campaign`, :mod:`rakectl.sim.compare`).

The code is :data:`ENTRY` and every module of ``rakectl`` and ``drivers`` it imports,
at any depth, function-level imports included (:func:`chain_modules`, read from the
sources as tests/test_layering.py reads them): a change to the daemon, the CLI or the
viewer, which no case runs, leaves the digest as it is. The compiled physics is built
from the same sources (drivers.compiled) and gives the same results to the bit, so it
does not count.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path

import drivers
from rakectl.errors import RakeError

ENTRY = "rakectl.sim.campaign"  # what runs a case (run_case)
UNRECORDED = ""  # the chain of a result written before results recorded theirs
PACKAGES = {"rakectl": Path(__file__).resolve().parents[1],
            "drivers": Path(drivers.__file__).resolve().parent}


class MixedChains(RakeError, ValueError):
    """Results of two versions of the code would be judged as one campaign's; the message
    names where each came from."""


def _source(name: str, packages: dict[str, Path]) -> Path | None:
    """The file of module ``name`` (of one of ``packages``), None if it is none of theirs."""
    top, _, rest = name.partition(".")
    if top not in packages:
        return None
    path = packages[top].joinpath(*rest.split(".")) if rest else packages[top]
    if (path / "__init__.py").is_file():
        return path / "__init__.py"
    return path.with_suffix(".py") if path.with_suffix(".py").is_file() else None


def _imports(path: Path, module: str) -> Iterator[str]:
    """Every module ``path`` (module ``module``) imports, and each one's packages;
    ``from pkg import name`` counts as ``pkg.name`` too (it may be a module)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_bytes(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        for name in names:
            parts = name.split(".")
            yield from (".".join(parts[:i]) for i in range(1, len(parts) + 1))


def chain_modules(packages: dict[str, Path], entry: str = ENTRY) -> dict[str, Path]:
    """``entry`` and every module of ``packages`` it imports, at any depth: name → file."""
    found: dict[str, Path] = {}
    todo = [entry]
    while todo:
        name = todo.pop()
        path = _source(name, packages)
        if name in found or path is None:
            continue
        found[name] = path
        todo += (m for m in _imports(path, name) if m not in found)
    return dict(sorted(found.items()))


def source_digest(packages: dict[str, Path], entry: str = ENTRY) -> str:
    """The digest of the chain's sources (:func:`chain_modules`), by module name."""
    h = hashlib.sha256()
    for name, path in chain_modules(packages, entry).items():
        h.update(f"{name}\0".encode())
        h.update(path.read_bytes() + b"\0")
    return h.hexdigest()[:12]


@functools.cache
def digest() -> str:
    """The digest of this process's chain (:data:`PACKAGES` as installed), read once."""
    return source_digest(PACKAGES)


def name(chain: str) -> str:
    """A chain as messages show it."""
    return chain or "unrecorded"


def counted(chains: Iterable[str]) -> str:
    """'abc (12 results), unrecorded (3 results)': the chains of some results."""
    found = Counter(chains)
    return ", ".join(f"{name(c)} ({n} result{'s' if n != 1 else ''})"
                     for c, n in sorted(found.items()))
