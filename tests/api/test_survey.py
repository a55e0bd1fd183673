"""`rakectl survey`: a mark taken on the daemon driving the emulated rake stands at or
above the true surface; the marks file, its errors, and the configuration it prints."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from drivers.objects import Contact
from drivers.soil import original_surface_height_m
from rakectl.api import survey
from rakectl.bench.tick import LockstepRig
from rakectl.config.loader import load_settings
from rakectl.config.settings import Settings
from rakectl.daemon.states import DaemonState
from rakectl.errors import ApiError, ConfigError
from tests.cli_run import run_rakectl
from tests.rig_commands import command, disarmed_rig
from tests.scripted_daemon import ScriptedDaemon

# what the mark may stand above the truth besides the declared error: the tine mount's
# compression by the currents' force reading and its 3 N margin (0.6 mm at 5 kN/m)
SLACK_M = 1.5e-3


@pytest.mark.parametrize("late_m", [0.0, 2e-3])
def test_a_mark_stands_at_or_above_the_true_surface(tmp_path: Path, late_m: float) -> None:
    """The engineer's part played by the emulator's truth: jog down (0.1 m/s, then 10 mm/s
    in the last 20 mm) until the tines are ``late_m`` into the soil, stop, and mark with
    that error declared. The point is at or above the soil's true surface there, by at
    most the mount's share; a mark while jogging is refused, naming the state. The mark
    goes through the CLI, over a real socket, from the daemon's own status reply."""
    rig = LockstepRig(tmp_path)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        emulator = rig.emulator
        soil = emulator.config.physics.ground.soil
        for k in range(20_000):
            reach_m, height_m = emulator.plant.tine_m()
            surface_m = original_surface_height_m(soil, reach_m)
            speed = 0.1 if height_m - surface_m > 0.02 else 0.01
            if k % 100 == 0:
                command(rig, json.dumps({"cmd": "jog", "space": "task",
                                          "height_m_per_s": -speed}).encode())
            rig.tick()
            if height_m <= surface_m - late_m:
                break
        assert emulator.ground.truth.contact is Contact.SOIL
        jogging = command(rig, b'{"cmd": "status"}')
        with pytest.raises(ApiError, match="the daemon is jog: mark with the rake held still"):
            survey.mark_from_status(jogging, late_m)
        command(rig, b'{"cmd": "stop"}')
        for _ in range(300):
            rig.tick()
        status = command(rig, b'{"cmd": "status"}')
        reach_m, tines_m = emulator.plant.tine_m()
        surface_m = original_surface_height_m(soil, reach_m)
    finally:
        rig.close()
    assert status["state"] == "hold" and tines_m <= surface_m  # in the soil, held
    path, marks = tmp_path / "rakectl.sock", tmp_path / "survey.yaml"
    daemon = ScriptedDaemon(path, [status])
    try:
        done = run_rakectl("survey", "mark", "--socket", str(path), "--file", str(marks),
                           "--error-mm", f"{late_m * 1e3:g}")
    finally:
        daemon.close()
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"survey: mark 1 in {marks}: reach ")
    (mark,) = survey.read_marks(marks)
    assert mark.reach_m == pytest.approx(reach_m, abs=1e-4)  # the tip's: the tines' offset
    assert surface_m <= mark.point.height_m <= surface_m + late_m + SLACK_M


def _mark(reach_m: float, height_m: float, error_m: float = 1e-3) -> survey.Mark:
    return survey.Mark(reach_m, height_m, error_m)


def test_show_prints_the_configuration_the_daemon_loads(tmp_path: Path) -> None:
    """Marks in any order; two at one reach keep the higher; the printed block is the
    configuration's descent.survey, as load_settings reads it."""
    marks = tmp_path / "survey.yaml"
    for m in (_mark(1.2, 0.010), _mark(0.8, -0.004), _mark(1.0, 0.002), _mark(1.0, 0.006)):
        survey.append_mark(marks, m)
    assert len(survey.read_marks(marks)) == 4
    done = run_rakectl("survey", "show", "--file", str(marks))
    assert done.returncode == 0, done.stderr
    assert "3 points, reach 0.800–1.200 m, widest gap 200 mm" in done.stderr
    config = tmp_path / "rakectl.yaml"
    config.write_text(done.stdout)
    loaded: Settings = load_settings(config)
    assert [(p.reach_m, p.height_m) for p in loaded.descent.survey] == [
        (0.8, -0.003), (1.0, 0.007), (1.2, 0.011)]
    lines = done.stdout.splitlines()  # its survey: lines, into a descent: section there
    assert lines[0].startswith("#") and lines[2] == "descent:"
    config.write_text("descent:\n  ceiling_m: 0.05\n" + "\n".join(lines[3:]) + "\n")
    loaded = load_settings(config)
    assert loaded.descent.ceiling_m == 0.05 and len(loaded.descent.survey) == 3


def test_a_point_above_the_ceiling_is_named_and_nothing_is_printed(tmp_path: Path) -> None:
    marks, config = tmp_path / "survey.yaml", tmp_path / "rakectl.yaml"
    survey.append_mark(marks, _mark(0.9, 0.01))
    survey.append_mark(marks, _mark(1.1, 0.03))
    config.write_text("descent:\n  ceiling_m: 0.02\n")
    done = run_rakectl("survey", "show", "--file", str(marks), "--config", str(config))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip() == (f"rakectl: error: {marks}: descent.survey[1].height_m must "
                                   "be <= descent.ceiling_m (0.02 m), got 0.031")


@pytest.mark.parametrize(("text", "message"), [
    ("marks: 3\n", "no 'marks' list"),
    ("marks:\n  - {reach_m: 1.0, tines_height_max_m: 0.0}\n", "marks[0]: expected reach_m"),
    ("marks:\n  - {reach_m: .nan, tines_height_max_m: 0.0, error_m: 0.001}\n",
     "marks[0]: a number is not finite"),
    ("marks: [\n", "not a survey file"),
    ("marks:\n  - {reach_m: 1" + "0" * 400 + ", tines_height_max_m: 0.0, error_m: 0.001}\n",
     "marks[0]: expected reach_m"),  # past any float
    ("marks:\n  - {reach_m: 1.0, tines_height_max_m: 0.0, error_m: -0.005}\n",
     "marks[0]: error_m must be within 0–0.05 m, as `survey mark` takes it, got -0.005"),
    # taken as 1.0 and 1.1 m before
    ("marks:\n  - {reach_m: true, tines_height_max_m: 0.0, error_m: 0.001}\n",
     "marks[0]: expected reach_m"),
    ("marks:\n  - {reach_m: '1.1', tines_height_max_m: 0.0, error_m: 0.001}\n",
     "marks[0]: expected reach_m"),
])
def test_a_bad_marks_file_is_named_and_not_written(tmp_path: Path, text: str,
                                                   message: str) -> None:
    marks = tmp_path / "survey.yaml"
    marks.write_text(text)
    with pytest.raises(ConfigError, match=f"^{marks}: .*{message}".replace("[", r"\[")) as e:
        survey.append_mark(marks, _mark(1.0, 0.0))
    assert "\n" not in str(e.value)  # one line, the YAML error's too
    assert marks.read_text() == text  # the engineer's marks stay as they were


@pytest.mark.parametrize(("mark", "message"), [
    (_mark(-1.0, 0.0), "marks[1]: descent.survey's reach_m must be >= 0, got -1"),
    (_mark(1.0, -3.0), "marks[1]: descent.survey's height_m must be >= -0.5, got -2.999"),
])
def test_a_point_out_of_its_declared_bounds_is_named_and_nothing_is_printed(
        tmp_path: Path, mark: survey.Mark, message: str) -> None:
    """``show`` judges each point by the bounds the loader would: a block it printed is
    one the daemon loads. The mark is named as the file has it (the second here: the
    sorted block's first, which the message named before)."""
    marks = tmp_path / "survey.yaml"
    survey.append_mark(marks, _mark(9.0, 0.0))
    survey.append_mark(marks, mark)
    done = run_rakectl("survey", "show", "--file", str(marks))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip() == f"rakectl: error: {marks}: {message}"


@pytest.mark.parametrize(("reply", "error_m", "message"), [
    ({"state": "hold", "tip": {"reach_m": 1.0, "tines_height_max_m": 0.0}}, -1e-3,
     "--error-mm must be within 0–50 mm, got -1"),
    ({"state": "hold", "tip": {"reach_m": 1.0, "tines_height_max_m": 0.0}}, math.nan,
     "--error-mm must be within"),
    ({"state": "fault", "tip": {"reach_m": 1.0, "tines_height_max_m": 0.0}}, 1e-3,
     "the daemon is fault"),
    ({"state": "armed", "tip": {"reach_m": None, "tines_height_max_m": None}}, 1e-3,
     "reports no pose"),
    ({"state": "armed", "tip": {"reach_m": 1.0, "depth_m": 0.0}}, 1e-3, "reports no pose"),
])
def test_a_mark_the_status_cannot_give_is_refused(reply: dict[str, Any], error_m: float,
                                                  message: str) -> None:
    """A bad --error-mm is the operator's value (ConfigError, exit status 2); the others
    are the daemon's state (ApiError)."""
    bad_value = not survey.error_in_range(error_m)
    with pytest.raises(ConfigError if bad_value else ApiError, match=message):
        survey.mark_from_status(reply, error_m)


@pytest.mark.parametrize(("error_mm", "status", "expected"), [
    ("2", 3, "cannot reach the rakectl daemon"),  # the daemon cannot be reached
    ("-1", 2, "survey: --error-mm must be within 0–50 mm, got -1"),  # before it is asked
    ("nan", 2, "survey: --error-mm must be within 0–50 mm, got nan")])
def test_marking_without_a_daemon_or_with_a_bad_error_writes_nothing(
        tmp_path: Path, error_mm: str, status: int, expected: str) -> None:
    marks = tmp_path / "survey.yaml"
    done = run_rakectl("survey", "mark", "--socket", str(tmp_path / "none.sock"),
                       "--file", str(marks), "--error-mm", error_mm)
    assert done.returncode == status and done.stderr.startswith(f"rakectl: error: {expected}")
    assert len(done.stderr.strip().splitlines()) == 1
    assert not marks.exists()


def test_a_survey_file_that_cannot_be_written_is_said_before_the_daemon_is_asked(
        tmp_path: Path) -> None:
    """No daemon listens here: the file's problem comes first, in one line; and a write
    that fails names the file (not the '.partial' beside it)."""
    marks = tmp_path / "no" / "survey.yaml"
    done = run_rakectl("survey", "mark", "--socket", str(tmp_path / "none.sock"),
                       "--file", str(marks), "--error-mm", "1")
    assert done.returncode == 2
    assert done.stderr.strip() == (f"rakectl: error: {marks}: cannot write the survey file: "
                                   f"no directory {marks.parent}")
    with pytest.raises(ConfigError, match=f"^{marks}: cannot write the survey file: "):
        survey.append_mark(marks, _mark(1.0, 0.0))


def test_a_non_finite_lift_withholds_only_the_mark_height(tmp_path: Path) -> None:
    """The status reply's tip: a force reading gone non-finite leaves the tines' height
    unknown (null: no mark can be taken) while the pose, from finite encoders, stands."""
    with disarmed_rig(tmp_path) as rig:
        rig.daemon.supervisor.f_current_n = math.nan
        tip = command(rig, b'{"cmd": "status"}')["tip"]
    assert tip["tines_height_max_m"] is None
    assert math.isfinite(tip["reach_m"]) and math.isfinite(tip["depth_m"])


@pytest.mark.parametrize(("action", "says"), [
    ((), ("descent.survey", "jog the tines down", "docs/installation.md")),
    (("mark",), ("Mark the surface", "Use it while surveying a site", "armed or hold",
                 "--error-mm")),
    (("show",), ("descent.survey block", "Use it once the site is marked",
                 "descent.ceiling_m", "systemctl restart rakectl"))])
def test_the_help_says_what_each_survey_command_does_and_when(
        action: tuple[str, ...], says: tuple[str, ...]) -> None:
    """`rakectl survey [mark|show] --help`: a description under the usage, what the
    command does and when in the site's survey it is used (before, the usage went
    straight to the options)."""
    done = run_rakectl("survey", *action, "--help")
    assert done.returncode == 0, done.stderr
    description = " ".join(done.stdout.split("\n\n")[1].split())
    assert not description.startswith(("options:", "positional arguments:")), done.stdout
    for words in says:
        assert words in description, (words, description)
