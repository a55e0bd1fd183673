"""The daemon's state table."""

from __future__ import annotations

import pytest

from rakectl.daemon.states import ARMED_STATES, TRANSITIONS, DaemonState, Event, next_state


def test_happy_path() -> None:
    state = DaemonState.INIT
    for event, expected in [(Event.READY, DaemonState.DISARMED), (Event.ARM, DaemonState.ARMED),
                            (Event.JOG, DaemonState.JOG), (Event.STOP, DaemonState.HOLD),
                            (Event.EXCAVATE, DaemonState.EXCAVATE), (Event.DONE, DaemonState.HOLD),
                            (Event.DISARM, DaemonState.DISARMED)]:
        new = next_state(state, event)
        assert new is expected, (state, event)
        state = new


@pytest.mark.parametrize("state", list(DaemonState))
def test_estop_is_reachable_from_everywhere_and_fault_from_all_but_estop(
        state: DaemonState) -> None:
    assert next_state(state, Event.ESTOP) is DaemonState.ESTOP
    expected = None if state is DaemonState.ESTOP else DaemonState.FAULT
    assert next_state(state, Event.FAULT) is expected


def test_reset_only_from_fault_or_estop() -> None:
    for state in DaemonState:
        allowed = next_state(state, Event.RESET)
        latched = state in (DaemonState.FAULT, DaemonState.ESTOP)
        assert (allowed is DaemonState.DISARMED) == latched


def test_motion_only_from_armed_states_and_never_straight_between_modes() -> None:
    for (state, _event), new in TRANSITIONS.items():
        if new in (DaemonState.JOG, DaemonState.EXCAVATE):
            assert state in ARMED_STATES
    assert next_state(DaemonState.JOG, Event.EXCAVATE) is None
    assert next_state(DaemonState.EXCAVATE, Event.JOG) is None
    assert next_state(DaemonState.DISARMED, Event.JOG) is None
    assert next_state(DaemonState.FAULT, Event.ARM) is None


def test_the_first_arming_goes_through_the_weight_check() -> None:
    assert next_state(DaemonState.DISARMED, Event.CHECK) is DaemonState.CHECKING
    assert next_state(DaemonState.CHECKING, Event.CHECKED) is DaemonState.ARMED
    assert DaemonState.CHECKING in ARMED_STATES  # the drives hold the rake while it runs
    for event in (Event.JOG, Event.EXCAVATE, Event.STOP, Event.ARM):
        assert next_state(DaemonState.CHECKING, event) is None, event
    assert next_state(DaemonState.CHECKING, Event.DISARM) is DaemonState.DISARMED
    assert next_state(DaemonState.CHECKING, Event.FAULT) is DaemonState.FAULT
    assert next_state(DaemonState.ARMED, Event.CHECKED) is None
