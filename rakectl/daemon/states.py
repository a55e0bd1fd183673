"""The daemon's operating states and their transitions, as data (pure).

    INIT ──ready──▶ DISARMED ──arm──▶ ARMED ──jog──▶ JOG ──stop/done──▶ HOLD
                     ▲  │               ▲  └─excavate─▶ EXCAVATE ─stop/done─┘
                     │  └─arm (first)─▶ CHECKING ─checked─┘
                     └────disarm───── (from CHECKING, ARMED, JOG, EXCAVATE, HOLD)
    any state ──fault──▶ FAULT ──reset (cause cleared)──▶ DISARMED
    any state ──estop──▶ ESTOP ──reset──▶ DISARMED

The first arming after start-up goes through CHECKING, the weight check
(rakectl.core.selftest): drives enabled, the tip lifted and lowered back;
jogging and excavating wait for ARMED. A failed check is a fault.
The drives' power stages are enabled only in the armed states. A request
that the table does not allow is refused with a message naming the state.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from types import MappingProxyType


class DaemonState(enum.Enum):
    INIT = 0  # bringing the drives up
    DISARMED = 1  # drives disabled, 0 V
    ARMED = 2  # drives enabled, holding the pose where it was armed
    JOG = 3  # following the operator's velocity commands (dead-man)
    EXCAVATE = 4  # raking a lane
    HOLD = 5  # holding after a stop, a finished excavation or a find
    FAULT = 6  # 0 V, drives disabled, until reset once the cause has cleared
    ESTOP = 7  # emergency stop: 0 V, drives disabled (quick stop), until reset
    CHECKING = 8  # drives enabled, the weight check before the first arming running


class Event(enum.Enum):
    READY = enum.auto()  # bring-up done, first valid feedback
    ARM = enum.auto()
    CHECK = enum.auto()  # arm, with the weight check first
    CHECKED = enum.auto()  # the checks before arming passed (weight, tine mount)
    DISARM = enum.auto()
    JOG = enum.auto()
    EXCAVATE = enum.auto()
    STOP = enum.auto()  # operator stop, dead-man expiry
    DONE = enum.auto()  # excavation finished or object found
    FAULT = enum.auto()
    ESTOP = enum.auto()
    RESET = enum.auto()


ARMED_STATES = frozenset({DaemonState.CHECKING, DaemonState.ARMED, DaemonState.JOG,
                          DaemonState.EXCAVATE, DaemonState.HOLD})


def _table() -> dict[tuple[DaemonState, Event], DaemonState]:
    table: dict[tuple[DaemonState, Event], DaemonState] = {
        (DaemonState.INIT, Event.READY): DaemonState.DISARMED,
        (DaemonState.DISARMED, Event.ARM): DaemonState.ARMED,
        (DaemonState.DISARMED, Event.CHECK): DaemonState.CHECKING,
        (DaemonState.CHECKING, Event.CHECKED): DaemonState.ARMED,
        (DaemonState.FAULT, Event.RESET): DaemonState.DISARMED,
        (DaemonState.ESTOP, Event.RESET): DaemonState.DISARMED,
    }
    for armed in ARMED_STATES:
        table[(armed, Event.DISARM)] = DaemonState.DISARMED
        table[(armed, Event.JOG)] = DaemonState.JOG
        table[(armed, Event.EXCAVATE)] = DaemonState.EXCAVATE
        table[(armed, Event.STOP)] = DaemonState.HOLD
    table[(DaemonState.EXCAVATE, Event.DONE)] = DaemonState.HOLD
    # switching straight between jogging and excavating, or from one lane to another, is
    # refused: stop first
    del table[(DaemonState.JOG, Event.EXCAVATE)]
    del table[(DaemonState.EXCAVATE, Event.JOG)]
    del table[(DaemonState.EXCAVATE, Event.EXCAVATE)]
    # nothing moves the rake but the weight check until it has passed
    for event in (Event.JOG, Event.EXCAVATE, Event.STOP):
        del table[(DaemonState.CHECKING, event)]
    for state in DaemonState:
        table[(state, Event.ESTOP)] = DaemonState.ESTOP
        if state is not DaemonState.ESTOP:
            table[(state, Event.FAULT)] = DaemonState.FAULT
    return table


TRANSITIONS: Mapping[tuple[DaemonState, Event], DaemonState] = MappingProxyType(_table())


def next_state(state: DaemonState, event: Event) -> DaemonState | None:
    """The state after ``event``, or None if the table does not allow it."""
    return TRANSITIONS.get((state, event))
