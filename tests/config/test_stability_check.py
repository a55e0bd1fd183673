"""Load-time refusal of an unstable impedance loop, and the delay's whole-period message."""

from __future__ import annotations

from pathlib import Path

import pytest

from rakectl.config.loader import load_settings
from rakectl.config.settings import Settings
from rakectl.errors import ConfigError
from rakectl.sim.scenario import Scenario

ROOT = Path(__file__).resolve().parents[2]
DAEMON_FILES = sorted(p for p in (ROOT / "config").glob("*.yaml")
                      if not p.name.startswith("emulator"))  # those are drivers' roots
SCENARIOS = sorted((ROOT / "config" / "scenarios").glob("*.yaml"))


def _error(path: Path | None, overrides: list[str], root: type = Scenario) -> str:
    with pytest.raises(ConfigError) as info:
        load_settings(path, overrides, root=root)
    return str(info.value)


@pytest.mark.parametrize("root", [Settings, Scenario])
def test_the_papers_damping_in_the_wrong_unit_is_refused(tmp_path: Path, root: type) -> None:
    """B_d = 13.3 N·s/mm entered as 13.3 N·s/m: the loop diverges (F̂ 5.9e12 N). Its
    radius is the largest over the position loops tried, at the fastest (0.02 s)."""
    path = tmp_path / "rakectl.yaml"
    path.write_text("impedance:\n  mass_kg: 0.39\n  damping_ns_per_m: 13.3\n")
    message = _error(path, [], root)
    assert f"{path}:3: impedance.damping_ns_per_m 13.3 N·s/m makes the impedance loop " \
        "unstable: the nominal discrete loop has spectral radius 1.13639 (stable needs < 1)" \
        in message
    assert "estimator.environment_stiffness_n_per_m 200000, delay_s 0.01, rate_hz 1000 " \
        "and a position loop P(s) = 1/(0.02 s + 1)" in message
    assert "\n" not in message


@pytest.mark.parametrize(("override", "named"), [
    ("impedance.damping_ns_per_m=250", "impedance.damping_ns_per_m 250 N·s/m makes"),  # < 278
    ("estimator.environment_stiffness_n_per_m=2e7",  # unstable above about 1.13e7 N/m
     "estimator.environment_stiffness_n_per_m 2e+07 N/m makes"),
])
def test_an_unstable_loop_is_named_by_the_option_changed(override: str, named: str) -> None:
    message = _error(ROOT / "config/scenarios/paper-fig5.yaml", [override])
    assert f"--set {override}: {named} the impedance loop unstable" in message
    assert "(stable needs < 1)" in message


def test_an_option_that_does_not_make_it_unstable_is_not_blamed() -> None:
    """A stiffer damping (stabler) given with an unstable K_e: the K_e is named, though
    the damping was given first; two that are each unstable are named together."""
    message = _error(None, ["impedance.damping_ns_per_m=2e4",
                            "estimator.environment_stiffness_n_per_m=2e8"])
    assert "estimator.environment_stiffness_n_per_m 2e+08 N/m makes the impedance loop" \
        in message
    message = _error(None, ["impedance.damping_ns_per_m=100",
                            "estimator.environment_stiffness_n_per_m=5e7"])
    assert ": impedance and estimator values together make the impedance loop unstable" \
        in message


def test_the_radius_takes_the_scenarios_own_position_loop_too() -> None:
    """B_d 500 N·s/m is stable with every position loop tried (0.02–0.2 s), not with a
    scenario's first-order plant of 5 ms."""
    load_settings(None, ["impedance.damping_ns_per_m=500"], root=Scenario)
    message = _error(None, ["impedance.damping_ns_per_m=500", "plant.time_constant_s=0.005"])
    assert "P(s) = 1/(0.005 s + 1)" in message


@pytest.mark.parametrize("path", DAEMON_FILES, ids=lambda p: p.name)
def test_every_shipped_daemon_configuration_loads(path: Path) -> None:
    load_settings(path, root=Settings)


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_every_shipped_scenario_loads(path: Path) -> None:
    load_settings(path, root=Scenario)


def test_the_defaults_load() -> None:
    load_settings(None, root=Settings)
    load_settings(None, root=Scenario)


def test_a_rate_that_splits_the_delay_names_both_values() -> None:
    """A user who changes rate_hz learns that it is what clashes with delay_s."""
    message = _error(ROOT / "config/scenarios/paper-fig5.yaml", ["rate_hz=50"])
    assert message.endswith(
        "paper-fig5.yaml:13: estimator.delay_s 0.01 s is not a whole number of loop periods "
        "at rate_hz 50 (0.02 s): the estimator delays by whole ticks; change one or the other")


def test_a_delay_longer_than_the_check_covers_is_refused() -> None:
    message = _error(None, ["estimator.max_delay_s=2", "estimator.delay_s=1",
                            "rate_hz=1250"])
    assert "estimator.delay_s 1 s is 1250 loop periods at rate_hz 1250: the load-time " \
        "stability check covers at most 250" in message
