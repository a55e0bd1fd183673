"""Configuration: every bad input gives one line naming file, line and key."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from rakectl.cli.docs import configuration_reference
from rakectl.config.loader import load_settings
from rakectl.config.settings import Settings
from rakectl.errors import ConfigError
from rakectl.sim.scenario import PlantKind, Scenario


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "rakectl.yaml"
    path.write_text(text)
    return path


def _error(path: Path | None, overrides: tuple[str, ...] = ()) -> str:
    with pytest.raises(ConfigError) as info:
        load_settings(path, overrides, root=Scenario)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_defaults_load_and_are_frozen() -> None:
    settings = load_settings()
    assert settings == Settings()
    with pytest.raises(AttributeError):
        settings.rate_hz = 5.0  # type: ignore[misc]


def test_scenario_file_loads(tmp_path: Path) -> None:
    path = _write(tmp_path, "plant:\n  kind: first_order\n  time_constant_s: 0.1\nrate_hz: 500\n")
    settings = load_settings(path, root=Scenario)
    assert settings.plant.kind is PlantKind.FIRST_ORDER
    assert settings.plant.time_constant_s == 0.1
    assert settings.rate_hz == 500.0


@pytest.mark.parametrize("section", ["plant:\n  kind: rake\n", "trajectory:\n  kind: step\n",
                                     "duration_s: 5\n", "emulator:\n  seed: 1\n"])
def test_the_daemons_configuration_has_no_simulation_sections(tmp_path: Path,
                                                              section: str) -> None:
    with pytest.raises(ConfigError, match="is not a known option"):
        load_settings(_write(tmp_path, section))
    load_settings(_write(tmp_path, section), root=Scenario)


def test_number_literals_yaml_1_1_would_read_as_strings(tmp_path: Path) -> None:
    assert load_settings(_write(tmp_path, "impedance:\n  damping_ns_per_m: 1.33e4\n")) \
        .impedance.damping_ns_per_m == 13300.0


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("impedance:\n  mass_kg: 1\n  damping_ns_per_m: -3\n",
         ":3: impedance.damping_ns_per_m must be > 0, got -3"),
        ("impedance:\n  dampin_ns_per_m: 3\n",
         ":2: impedance.dampin_ns_per_m is not a known option (did you mean damping_ns_per_m?)"),
        ("bogus: 1\n", ":1: bogus is not a known option"),
        ("impedance:\n  mass_kg: heavy\n", ":2: impedance.mass_kg must be a number, got 'heavy'"),
        ("impedance:\n  mass_kg: true\n", ":2: impedance.mass_kg must be a number, got True"),
        ("impedance:\n  mass_kg: .nan\n", ":2: impedance.mass_kg must be finite, got nan"),
        ("rate_hz: 1" + "0" * 400 + "\n",  # past any float: not an OverflowError
         ":1: rate_hz must be finite, got a whole number of 401 digits"),
        ("drives:\n  r_node_id: '1e0'\n",
         ":2: drives.r_node_id must be a whole number, got '1e0'"),
        ("impedance: 3\n", ":1: impedance must be a section"),
        ("rate_hz:\n  a: 1\n", ":1: rate_hz must be a single value"),
        ("plant:\n  kind: cubic\n", ":2: plant.kind must be one of first_order, rake, got 'cubic'"),
        ("impedance:\n  mass_kg: [1\n", ": malformed YAML: expected ',' or ']'"),
        ("- 1\n- 2\n", ":1: the top level must be a mapping"),
        ("rate_hz: 100\nrate_hz: 200\n", ":2: rate_hz is given twice"),
        ("estimator:\n  delay_s: 0.6\n",
         ":2: estimator.delay_s must be <= estimator.max_delay_s (0.5)"),
        ("estimator:\n  delay_s: 0.0105\n",
         ":2: estimator.delay_s 0.0105 s is not a whole number of loop periods at rate_hz "
         "1000 (0.001 s)"),
        ("geometry:\n  r_min_m: 1.0\n  r_max_m: 0.5\n",
         ":3: geometry.r_max_m must be > geometry.r_min_m (1)"),
        ("daemon:\n  rt_mode: on\n",
         ":2: daemon.rt_mode must be one of enforce, ignore, off, got 'on'"),
        ("", ": no settings in the file"),
        ("# only a comment\n", ": no settings in the file"),
        ("drives:\n  sync_counter_overflow: 1\n",
         ":2: drives.sync_counter_overflow must be 0 (SYNC without counter) or 2 … 240"),
        ("drives:\n  heartbeat_period_ms: 300\n  heartbeat_timeout_ms: 900\n"
         "daemon:\n  boot_timeout_s: 0.5\n",
         ":5: daemon.boot_timeout_s must be >= 2 drives.heartbeat_period_ms (300 ms): "
         "bring-up waits that long"),
        # a traceback before (yaml's ParserError, ConstructorError, RecursionError)
        ("clamp:\n", ":1: clamp must be a section"),
        ("rate_hz: !foo 1\n", ":1: unsupported YAML: the explicit tag '!foo'"),
        ("rate_hz: !!python/object:os.system x\n", ":1: unsupported YAML: the explicit tag "
         "'tag:yaml.org,2002:python/object:os.system'"),
        # a standard tag made a value of another kind: a string tagged as one read as 3.0
        ("impedance:\n  damping_ns_per_m: !!str 3\n", ":2: unsupported YAML: the explicit "
         "tag 'tag:yaml.org,2002:str'"),
        ("lane:\n  adaptive: !!bool \"yes\"\n", ":2: unsupported YAML: the explicit tag"),
        ("clamp: !!map\n  force_limit_n: 70\n", ":1: unsupported YAML: the explicit tag"),
        ("bus:\n  trace_path:\n", ':2: bus.trace_path must be a string, got no value (an '
         'empty one: "")'),
        ("b: &b {x: 1}\nclamp:\n  <<: *b\n", ":3: unsupported YAML: could not determine a "
         "constructor for the tag 'tag:yaml.org,2002:merge'"),
        ("a: &x [*x]\n", ":1: a value that contains itself"),
        # read as another value before: YAML 1.1's octal, binary, base 60, underscores
        ("drives:\n  r_node_id: 010\n", ":2: drives.r_node_id: '010' has a leading zero"),
        ("drives:\n  r_node_id: 0b11\n", ":2: drives.r_node_id must be a number in "
         "decimal, 0x hexadecimal or 0o octal (YAML 1.2), got '0b11'"),
        ("rate_hz: 16:40\n", ":1: rate_hz must be a number in decimal"),
        ("rate_hz: 1_000\n", ":1: rate_hz must be a number in decimal"),
        # a NUL passed --check and stopped the daemon with a traceback at its first use
        ('daemon:\n  socket_path: "/run/a\\0b.sock"\n',
         ":2: daemon.socket_path must not contain a NUL character"),
    ],
)
def test_bad_files_name_file_line_and_key(tmp_path: Path, text: str, expected: str) -> None:
    path = _write(tmp_path, text)
    message = _error(path)
    assert message.startswith(str(path))
    assert expected in message


def test_hexadecimal_and_octal_integers_read_as_yaml_1_2_reads_them(tmp_path: Path) -> None:
    """A vendor-ID as CANopen tools print it (0x…), and 0o octal, which YAML 1.1 read as
    a string."""
    path = _write(tmp_path, "drives:\n  r_vendor_id: 0x2F\n  r_product_code: 0o17\n")
    drives = load_settings(path, (), root=Scenario).drives
    assert (drives.r_vendor_id, drives.r_product_code) == (47, 15)


def test_a_file_that_is_not_utf8_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes("daemon:\n  socket_group: op\xe9rateurs\n".encode("latin-1"))
    assert _error(path).endswith("latin1.yaml: not UTF-8 text (byte 0xe9 at offset 26)")


def test_set_names_the_value_as_written(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=re.escape(
            "--set daemon.rt_mode=on: daemon.rt_mode must be one of enforce, ignore, off, "
            "got 'on'")):
        load_settings(None, ["daemon.rt_mode=on"])
    assert load_settings(None, ["daemon.rt_mode=Off"]).daemon.rt_mode.value == "off"


def test_missing_file_is_one_line(tmp_path: Path) -> None:
    message = _error(tmp_path / "absent.yaml")
    assert "absent.yaml: cannot read" in message


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("impedance.damping_ns_per_m=-3",
         "--set impedance.damping_ns_per_m=-3: impedance.damping_ns_per_m must be > 0, got -3"),
        ("impedance.nope=1", "impedance.nope is not a known option"),
        ("nothing", "--set nothing: expected dotted.key=value"),
        ("=3", "expected dotted.key=value"),
        ("rate_hz=fast", "rate_hz must be a number, got 'fast'"),
        ("impedance=3", "impedance must be a section"),
        ("desired_force_n=120", "desired_force_n must be <= 90, got 120"),
        # what a file refuses: a merge key was merged, a recursive alias a RecursionError
        ("lane={<<: {depth_step_m: 0.02}}", "unsupported YAML: could not determine a "
         "constructor for the tag 'tag:yaml.org,2002:merge'"),
        ("lane=&a [*a]", "a value that contains itself"),
        ("impedance.damping_ns_per_m=!!float 3", "unsupported YAML: the explicit tag"),
        ("rate_hz=", "rate_hz must be a number, got ''"),
        ("drives.r_node_id=010", "drives.r_node_id: '010' has a leading zero"),
    ],
)
def test_bad_overrides_are_named(override: str, expected: str) -> None:
    assert expected in _error(None, (override,))


def test_an_override_with_nothing_after_the_sign_is_an_empty_string() -> None:
    """`--set bus.trace_path=` turns the trace off, as the reference says an empty value
    does; before, nothing read as YAML's null and was refused as no string."""
    base = load_settings(None, ["bus.trace_path=/tmp/t.log", "daemon.socket_group=adm"])
    assert (base.bus.trace_path, base.daemon.socket_group) == ("/tmp/t.log", "adm")
    settings = load_settings(None, ["bus.trace_path=/tmp/t.log", "bus.trace_path=",
                                    "daemon.socket_group= "])
    assert (settings.bus.trace_path, settings.daemon.socket_group) == ("", "")


def test_overrides_can_give_lists_of_sections() -> None:
    settings = load_settings(
        None, ["emulator.ground.objects.mines=[{reach_m: 1.0, depth_m: 0.06}]"], root=Scenario
    )
    assert isinstance(settings, Scenario)
    (mine,) = settings.emulator.ground.objects.mines
    assert (mine.reach_m, mine.depth_m) == (1.0, 0.06)
    message = _error_root("emulator.ground.objects.mines=[{reach_m: -1}]")
    assert "emulator.ground.objects.mines[0].reach_m must be" in message


def _error_root(override: str) -> str:
    from rakectl.sim.scenario import Scenario

    with pytest.raises(ConfigError) as info:
        load_settings(None, [override], root=Scenario)
    return str(info.value)


def test_yaml_1_1_booleans_map_back_to_enum_words(tmp_path: Path) -> None:
    settings = load_settings(_write(tmp_path, "daemon:\n  rt_mode: off\n"))
    assert settings.daemon.rt_mode.value == "off"
    assert load_settings(None, ["daemon.rt_mode=off"]).daemon.rt_mode.value == "off"


def test_overrides_apply_on_top_of_the_file(tmp_path: Path) -> None:
    path = _write(tmp_path, "estimator:\n  delay_s: 0.02\n")
    settings = load_settings(path, ["estimator.delay_s=0.03", "plant.kind=first_order"],
                             root=Scenario)
    assert settings.estimator.delay_s == 0.03


def test_reference_lists_every_option_with_unit_and_bounds() -> None:
    text = configuration_reference()
    assert "| impedance.damping_ns_per_m | float | `13300` | N·s/m | > 0, ≤ 1e+08 |" in text
    assert "| plant.kind | first_order \\| rake | `first_order` |" in text


def test_a_section_given_in_part_keeps_its_declared_defaults(tmp_path: Path) -> None:
    """One option of the r motor (or of θ's loop, or of the emulated r motor) set: the
    others stay the section's default as its parent declares it. They were the class's
    (θ's geared motor for r: 2.7× the r joint's length per count, its clamp on θ's
    model), with --check passing."""
    from drivers.settings import EmulatorConfig

    defaults = Settings()
    settings = load_settings(_write(tmp_path, "motors:\n  r:\n    supply_voltage_v: 24.0\n"
                                    "joint_control:\n  theta:\n    kp_v_per_unit: 1300\n"))
    assert settings.motors.r == defaults.motors.r
    assert settings.motors.r.lead_m_per_rev == 0.01 and settings.motors.r.gear_ratio == 1.0
    assert settings.joint_control.theta == dataclasses.replace(
        defaults.joint_control.theta, kp_v_per_unit=1300.0)
    assert settings.joint_control.theta.kff_v_s_per_unit == 7.0
    overridden = load_settings(None, ("motors.theta.current_limit_a=8",))
    assert overridden.motors.theta == dataclasses.replace(defaults.motors.theta,
                                                          current_limit_a=8.0)
    emulator = load_settings(None, ("physics.motor_r.current_noise_a=0.01",),
                             root=EmulatorConfig)
    assert emulator.physics.motor_r == dataclasses.replace(EmulatorConfig().physics.motor_r,
                                                           current_noise_a=0.01)


def test_a_survey_point_gives_both_its_reach_and_its_height(tmp_path: Path) -> None:
    """A point missing its height was put at 0 m (below a raised surface: the tines
    allowed deeper than the bound), one missing its reach at 1 m, and `{}` was a point."""
    for text, missing in (("[{reach_m: 0.9}]", "descent.survey[0].height_m"),
                          ("[{reach_m: 0.9, height_m: 0.01}, {height_m: 0.01}]",
                           "descent.survey[1].reach_m"),
                          ("[{}]", "descent.survey[0].reach_m")):
        path = _write(tmp_path, f"descent:\n  survey: {text}\n")
        assert _error(path) == f"{path}:2: {missing} is required"
    path = _write(tmp_path, "descent:\n  survey: [{reach_m: 0.9, height_m: 0.01}]\n")
    assert load_settings(path).descent.survey[0].height_m == 0.01


def test_node_ids_that_clash_are_both_named(tmp_path: Path) -> None:
    """Every clash read `drives.theta_node_id node-IDs … must differ`, whichever was set
    (the emulator's configuration too)."""
    from drivers.settings import EmulatorConfig

    path = _write(tmp_path, "drives:\n  r_node_id: 2\n")
    assert _error(path) == (f"{path}:2: drives.r_node_id and drives.theta_node_id are both "
                            "2: the drives' and the controller's node-IDs must differ")
    assert _error(None, ("drives.theta_node_id=1",)).endswith(
        "drives.r_node_id and drives.theta_node_id are both 1: the drives' and the "
        "controller's node-IDs must differ")
    with pytest.raises(ConfigError, match=r"drives\.r_node_id and drives\.controller_node_id "
                       r"are both 10: "):
        load_settings(None, ("drives.r_node_id=10",), root=EmulatorConfig)


def test_a_bit_rate_the_cycle_would_crowd_is_refused() -> None:
    """The link's rate is set outside rakectl; the option says what it is, and the 1 kHz
    cycle's 435 bits at 500 kbit/s would take 87 % of the bus before bit stuffing."""
    assert _error(None, ("bus.bitrate=500000",)) == (
        "--set bus.bitrate=500000: bus.bitrate 500000 bit/s: a cycle's 435 bits at 1000 Hz "
        "take 87 % of a 500000 bit/s bus before bit stuffing (at most 60 %; the robot runs "
        "1000 Hz on 1 Mbit/s)")
    assert _error(None, ("rate_hz=1500",)) == (  # named by what changed
        "--set rate_hz=1500: rate_hz 1500 Hz: a cycle's 435 bits at 1500 Hz take 65 % of a "
        "1000000 bit/s bus before bit stuffing (at most 60 %; the robot runs 1000 Hz on "
        "1 Mbit/s)")
    assert load_settings(None, ("bus.bitrate=500000", "rate_hz=500")).bus.bitrate == 500000


def test_the_physics_section_named_as_the_other_root_names_it_is_pointed_to() -> None:
    """A scenario's physics is its section emulator:, the emulator process's is physics:
    (its root is the emulator): each name given to the other is refused saying which."""
    from drivers.settings import EmulatorConfig

    assert "physics is not a known option (here it is emulator: emulator.…)" in \
        _error_root("physics.seed=3")
    with pytest.raises(ConfigError) as info:
        load_settings(None, ["emulator.seed=3"], root=EmulatorConfig)
    assert "emulator is not a known option (here it is physics: physics.…)" in str(info.value)
