"""The compiled physics (drivers.compiled): the same results as the Python physics, to the
last bit, used only by the sources it was built from, and chosen as asked."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from drivers import compiled

ROOT = Path(__file__).resolve().parents[2]
# two campaign cases with contact (tests/data/pinned): a plunge into the soil with no
# fault (28.7 N), a stroke the controller's SIGKILL ends (20.8 N)
CASES = (9745, 9742)
RUN = f"""
import sys
from drivers import compiled
from rakectl.sim.campaign import run_case
from rakectl.sim.cases import generate
print(compiled.status(), file=sys.stderr)
for index in {CASES!r}:
    print(repr(run_case(generate(20261127, index))))
"""


def _python(code: str, mode: str, cache: Path | str, cwd: Path = ROOT
            ) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, compiled.MODE_ENV: mode, compiled.CACHE_ENV: str(cache)}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_compiled_physics_gives_the_python_results_exactly(physics_build: Path) -> None:
    python = _python(RUN, "pure", physics_build)
    built = _python(RUN, "compiled", physics_build)
    assert python.returncode == 0 and built.returncode == 0, python.stderr + built.stderr
    assert python.stderr.startswith("physics: Python")
    assert built.stderr.startswith(f"physics: compiled (mypyc) from {physics_build}")
    results = python.stdout.splitlines()
    assert len(results) == len(CASES) and "f_true_z_max_n=28.7" in results[0]
    assert built.stdout.splitlines() == results  # every field, every digit


def test_auto_takes_the_build_only_when_there_is_one(physics_build: Path,
                                                     tmp_path: Path) -> None:
    code = "from drivers import arm, compiled; print(arm.__file__, compiled.running())"
    assert _python(code, "auto", physics_build).stdout.strip().endswith(".so compiled")
    assert _python(code, "auto", tmp_path).stdout.strip().endswith("arm.py python")
    assert _python(code, "pure", physics_build).stdout.strip().endswith("arm.py python")


def test_a_build_serves_only_the_sources_it_was_made_from(tmp_path: Path) -> None:
    """The build's name covers the physics and what it may import, not the rest."""
    for name in ("drivers", "rakectl"):
        shutil.copytree(ROOT / name, tmp_path / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    assert compiled.digest(tmp_path) == compiled.digest(ROOT)
    for path, changes in (("drivers/objects.py", True), ("drivers/soil_params.py", True),
                          ("rakectl/core/kinematics.py", True), ("rakectl/limits.py", True),
                          ("rakectl/daemon/loop.py", False), ("rakectl/sim/cases.py", False)):
        source = tmp_path / path
        before = source.read_bytes()
        source.write_bytes(before + b"\n")
        assert (compiled.digest(tmp_path) != compiled.digest(ROOT)) is changes, path
        source.write_bytes(before)


def test_a_bad_choice_of_physics_is_named(tmp_path: Path) -> None:
    bad = _python("import drivers", "fast", tmp_path)
    assert bad.returncode != 0
    assert "RAKECTL_PHYSICS='fast': expected one of auto, pure, compiled" in bad.stderr
    missing = _python("import drivers", "compiled", tmp_path)
    assert missing.returncode != 0
    assert "not built" in missing.stderr and "rakectl compile" in missing.stderr


def test_processes_a_compiled_one_starts_run_the_physics_asked_for(
        physics_build: Path, tmp_path: Path) -> None:
    """multiprocessing's spawn hands its children this process's sys.path: the build's
    entry there must not make the Python physics compiled (bench --campaign's runs). Run
    away from the sources, so that the package is imported as installed, not from the
    working directory."""
    code = ("from drivers import compiled\n"
            "from rakectl.bench.throughput import compare_physics\n"
            "c = compare_physics(first=9704, cases=1)\n"  # 8 ms of a lane
            "print(compiled.status(), c.python.physics, c.compiled.physics, sep='\\n')\n"
            "print(c.python.physics_kind, c.compiled.physics_kind)\n")
    out = _python(code, "auto", physics_build, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert [line.split(" (")[0] for line in out.stdout.splitlines()] == [
        "physics: compiled", "physics: Python", "physics: compiled", "python compiled"]
