"""The example configurations and systemd files: found in a checkout, shipped in a wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from rakectl.cli.main import main
from rakectl.config import files
from rakectl.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


def test_a_checkout_uses_its_own_files() -> None:
    assert files.config_dir() == ROOT / "config"
    assert (files.systemd_dir() / "rakectl.service").is_file()


def test_an_installed_package_finds_the_wheels_copy(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(files, "CHECKOUT", tmp_path / "site-packages")
    monkeypatch.setattr(files.sysconfig, "get_path", lambda name: str(tmp_path / "venv"))
    monkeypatch.setattr(files.sys, "prefix", str(tmp_path / "elsewhere"))
    monkeypatch.setattr(files.sys, "base_prefix", str(tmp_path / "elsewhere"))
    with pytest.raises(ConfigError, match="the example configuration is not installed"):
        files.shared_root()
    (tmp_path / "venv/share/rakectl/config").mkdir(parents=True)
    assert files.shared_root() == tmp_path / "venv/share/rakectl"


def test_files_copy_refuses_to_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    assert main(["files", "--copy", str(tmp_path)]) == 0
    assert (tmp_path / "systemd/rakectl.service").is_file()
    assert (tmp_path / "config/scenarios/paper-fig5.yaml").is_file()
    assert (tmp_path / "eds/roboteq_class_drive.eds").is_file()  # for a CANopen tool
    assert main(["files", "--copy", str(tmp_path)]) == 2
    assert "exists; copy into an empty directory" in capsys.readouterr().err
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "eds").mkdir()  # one of them there: nothing is copied
    assert main(["files", "--copy", str(tmp_path / "other")]) == 2
    assert not (tmp_path / "other" / "config").exists()


def test_files_says_where_the_eds_files_are(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["files", "--eds"]) == 0
    eds = Path(capsys.readouterr().out.strip())
    assert sorted(p.name for p in eds.glob("*.eds")) == [
        "dc_servo_drive.eds", "geared_motor_drive.eds", "roboteq_class_drive.eds"]


def test_the_wheel_ships_the_configurations_and_units(tmp_path: Path) -> None:
    """Built from a copy of what the wheel is made of: setuptools writes build/ and an
    egg-info into the tree it builds, which would be left in the working tree."""
    source = tmp_path / "source"
    for name in ("rakectl", "drivers", "config", "systemd"):
        shutil.copytree(ROOT / name, source / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                           str(tmp_path), str(source)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = tmp_path.glob("rakectl-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    data = "rakectl-0.1.0.data/data/share/rakectl/"
    for path in ("config/rakectl.yaml", "config/emulator-demo.yaml",
                 "config/scenarios/excavate-loam.yaml", "systemd/rakectl.service",
                 "systemd/rakectl.sysusers", "systemd/80-can0.network"):
        assert data + path in names, path
