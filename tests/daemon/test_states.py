"""The daemon's state table."""

from __future__ import annotations

import pytest

from rakectl.daemon.states import ARMED_STATES, TRANSITIONS, Event, State, next_state


def test_happy_path() -> None:
    state = State.INIT
    for event, expected in [(Event.READY, State.DISARMED), (Event.ARM, State.ARMED),
                            (Event.JOG, State.JOG), (Event.STOP, State.HOLD),
                            (Event.EXCAVATE, State.EXCAVATE), (Event.DONE, State.HOLD),
                            (Event.DISARM, State.DISARMED)]:
        new = next_state(state, event)
        assert new is expected, (state, event)
        state = new


@pytest.mark.parametrize("state", list(State))
def test_estop_is_reachable_from_everywhere_and_fault_from_all_but_estop(state: State) -> None:
    assert next_state(state, Event.ESTOP) is State.ESTOP
    assert next_state(state, Event.FAULT) is (None if state is State.ESTOP else State.FAULT)


def test_reset_only_from_fault_or_estop() -> None:
    for state in State:
        allowed = next_state(state, Event.RESET)
        assert (allowed is State.DISARMED) == (state in (State.FAULT, State.ESTOP))


def test_motion_only_from_armed_states_and_never_straight_between_modes() -> None:
    for (state, _event), new in TRANSITIONS.items():
        if new in (State.JOG, State.EXCAVATE):
            assert state in ARMED_STATES
    assert next_state(State.JOG, Event.EXCAVATE) is None
    assert next_state(State.EXCAVATE, Event.JOG) is None
    assert next_state(State.DISARMED, Event.JOG) is None
    assert next_state(State.FAULT, Event.ARM) is None
