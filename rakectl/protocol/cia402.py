"""The CiA 402 power state machine, pure: states, commands and the transition table as data.

Shared by the controller (decode the statusword, pick the next command of
:func:`path_to_enabled`) and the drive emulator (decode the controlword, apply
:data:`TRANSITIONS`, encode the statusword).

Statusword 0x6041: bit 0 ready to switch on, 1 switched on, 2 operation
enabled, 3 fault, 4 voltage enabled, 5 quick stop (0 = quick stop active),
6 switch on disabled, 7 warning, 9 remote, 10 target reached, 11 internal
limit active. The state is bits 0–3, 5, 6 (``x`` = either)::

    x0xx 0000  NOT_READY_TO_SWITCH_ON      x01x 0111  OPERATION_ENABLED
    x1xx 0000  SWITCH_ON_DISABLED          x00x 0111  QUICK_STOP_ACTIVE
    x01x 0001  READY_TO_SWITCH_ON          x0xx 1111  FAULT_REACTION_ACTIVE
    x01x 0011  SWITCHED_ON                 x0xx 1000  FAULT

Controlword 0x6040: bit 0 switch on, 1 enable voltage, 2 quick stop (0 =
quick stop), 3 enable operation, 7 fault reset (acts on its rising edge)::

    0xxx x110  SHUTDOWN                    0xxx xx0x  DISABLE_VOLTAGE
    0xxx 0111  SWITCH_ON                   0xxx x01x  QUICK_STOP
    0xxx 0111  DISABLE_OPERATION           0xxx 1111  ENABLE_OPERATION
    0→1 in bit 7  FAULT_RESET

SWITCH_ON and DISABLE_OPERATION are the same bits (the standard tells them
apart by the state they are received in), so ``Command.DISABLE_OPERATION`` is
an alias of ``Command.SWITCH_ON``. Transitions, numbered as in the standard's
figure (IEC 61800-7-201 / CiA 402-2)::

    0, 1  start → NOT_READY_TO_SWITCH_ON → SWITCH_ON_DISABLED   automatic
    2     SWITCH_ON_DISABLED → READY_TO_SWITCH_ON                 SHUTDOWN
    3     READY_TO_SWITCH_ON → SWITCHED_ON                        SWITCH_ON
    3+4   READY_TO_SWITCH_ON → OPERATION_ENABLED                  ENABLE_OPERATION
    4     SWITCHED_ON → OPERATION_ENABLED                         ENABLE_OPERATION
    5     OPERATION_ENABLED → SWITCHED_ON                         DISABLE_OPERATION
    6     SWITCHED_ON → READY_TO_SWITCH_ON                        SHUTDOWN
    7     READY_TO_SWITCH_ON → SWITCH_ON_DISABLED                 QUICK_STOP, DISABLE_VOLTAGE
    8     OPERATION_ENABLED → READY_TO_SWITCH_ON                  SHUTDOWN
    9     OPERATION_ENABLED → SWITCH_ON_DISABLED                  DISABLE_VOLTAGE
    10    SWITCHED_ON → SWITCH_ON_DISABLED                        DISABLE_VOLTAGE, QUICK_STOP
    11    OPERATION_ENABLED → QUICK_STOP_ACTIVE                   QUICK_STOP
    12    QUICK_STOP_ACTIVE → SWITCH_ON_DISABLED                  DISABLE_VOLTAGE
    13    any → FAULT_REACTION_ACTIVE                             a fault (:func:`on_fault`)
    14    FAULT_REACTION_ACTIVE → FAULT                           automatic
    15    FAULT → SWITCH_ON_DISABLED                              FAULT_RESET
    16    QUICK_STOP_ACTIVE → OPERATION_ENABLED                   ENABLE_OPERATION

A command the table has no entry for, in a given state, is ignored. The emulated drives
apply 0 V in QUICK_STOP_ACTIVE and stay there (as quick-stop option code 6
does) until DISABLE_VOLTAGE (12) or ENABLE_OPERATION (16); transition 12 is
never automatic.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from types import MappingProxyType
from typing import Final

from rakectl.errors import FrameError


class DriveState(enum.Enum):
    NOT_READY_TO_SWITCH_ON = enum.auto()
    SWITCH_ON_DISABLED = enum.auto()
    READY_TO_SWITCH_ON = enum.auto()
    SWITCHED_ON = enum.auto()
    OPERATION_ENABLED = enum.auto()
    QUICK_STOP_ACTIVE = enum.auto()
    FAULT_REACTION_ACTIVE = enum.auto()
    FAULT = enum.auto()


class DriveCommand(enum.Enum):
    """A device-control command; its value is the controlword that sends it."""

    DISABLE_VOLTAGE = 0x00
    QUICK_STOP = 0x02
    SHUTDOWN = 0x06
    SWITCH_ON = 0x07
    DISABLE_OPERATION = 0x07  # alias of SWITCH_ON: the same bits
    ENABLE_OPERATION = 0x0F
    FAULT_RESET = 0x80


class StatusFlag(enum.IntFlag):
    """Statusword bits that are not part of the state."""

    VOLTAGE_ENABLED = 0x0010
    WARNING = 0x0080
    REMOTE = 0x0200
    TARGET_REACHED = 0x0400
    INTERNAL_LIMIT_ACTIVE = 0x0800


NO_FLAGS: Final = StatusFlag(0)
FAULT_RESET_BIT: Final = 0x0080

# (mask, value, state) per the standard's statusword table; value has x = 0.
STATUSWORD_PATTERNS: Final = (
    (0x004F, 0x0000, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x004F, 0x0040, DriveState.SWITCH_ON_DISABLED),
    (0x006F, 0x0021, DriveState.READY_TO_SWITCH_ON),
    (0x006F, 0x0023, DriveState.SWITCHED_ON),
    (0x006F, 0x0027, DriveState.OPERATION_ENABLED),
    (0x006F, 0x0007, DriveState.QUICK_STOP_ACTIVE),
    (0x004F, 0x000F, DriveState.FAULT_REACTION_ACTIVE),
    (0x004F, 0x0008, DriveState.FAULT),
)
STATE_BITS_MASK: Final = 0x006F

# (mask, value, command) for controlwords with bit 7 clear.
CONTROLWORD_PATTERNS: Final = (
    (0x0002, 0x0000, DriveCommand.DISABLE_VOLTAGE),
    (0x0006, 0x0002, DriveCommand.QUICK_STOP),
    (0x0007, 0x0006, DriveCommand.SHUTDOWN),
    (0x000F, 0x0007, DriveCommand.SWITCH_ON),
    (0x000F, 0x000F, DriveCommand.ENABLE_OPERATION),
)


def _match_state(low_bits: int) -> DriveState | None:
    matches = [state for mask, value, state in STATUSWORD_PATTERNS if low_bits & mask == value]
    return matches[0] if matches else None


def _match_command(low_bits: int) -> DriveCommand:
    return next(cmd for mask, value, cmd in CONTROLWORD_PATTERNS if low_bits & mask == value)


_STATE_BY_LOW_BITS: Final = tuple(_match_state(bits) for bits in range(0x80))
_COMMAND_BY_LOW_BITS: Final = tuple(_match_command(bits) for bits in range(0x10))
_STATE_BITS: Final = MappingProxyType({state: value for _, value, state in STATUSWORD_PATTERNS})


def _check_word(name: str, word: int) -> None:
    if not (isinstance(word, int) and 0 <= word <= 0xFFFF):
        raise FrameError(f"{name} must be an int in 0..0xFFFF, got {word!r}")


def decode_statusword(statusword: int) -> DriveState:
    """The state a statusword reports; FrameError for a pattern the standard does not define."""
    _check_word("statusword", statusword)
    state = _STATE_BY_LOW_BITS[statusword & 0x7F]
    if state is None:
        raise FrameError(f"statusword 0x{statusword:04X} is no CiA 402 state")
    return state


def status_flags(statusword: int) -> StatusFlag:
    """The non-state bits of a statusword that :class:`StatusFlag` names."""
    _check_word("statusword", statusword)
    return StatusFlag(statusword) & ~StatusFlag(STATE_BITS_MASK)


def encode_statusword(state: DriveState, flags: StatusFlag = NO_FLAGS) -> int:
    """The statusword of ``state`` (don't-care bits 0) with ``flags`` set."""
    if flags & STATE_BITS_MASK:
        raise FrameError(f"status flags must leave the state bits alone, got 0x{flags:04X}")
    return _STATE_BITS[state] | int(flags)


def controlword(command: DriveCommand) -> int:
    """The controlword that sends ``command``."""
    return command.value


def decode_controlword(controlword: int, previous_controlword: int) -> DriveCommand | None:
    """The command a controlword gives after ``previous_controlword``.

    FAULT_RESET on a rising edge of bit 7; None while bit 7 stays set.
    """
    _check_word("controlword", controlword)
    if controlword & FAULT_RESET_BIT:
        return None if previous_controlword & FAULT_RESET_BIT else DriveCommand.FAULT_RESET
    return _COMMAND_BY_LOW_BITS[controlword & 0x0F]


# --------------------------------------------------------------------------- transitions

TRANSITIONS: Final[Mapping[tuple[DriveState, DriveCommand], DriveState]] = MappingProxyType({
    (DriveState.SWITCH_ON_DISABLED, DriveCommand.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,  # 2
    (DriveState.READY_TO_SWITCH_ON, DriveCommand.SWITCH_ON): DriveState.SWITCHED_ON,  # 3
    (DriveState.READY_TO_SWITCH_ON, DriveCommand.ENABLE_OPERATION):
        DriveState.OPERATION_ENABLED,  # 3+4
    (DriveState.SWITCHED_ON, DriveCommand.ENABLE_OPERATION): DriveState.OPERATION_ENABLED,  # 4
    (DriveState.OPERATION_ENABLED, DriveCommand.DISABLE_OPERATION): DriveState.SWITCHED_ON,  # 5
    (DriveState.SWITCHED_ON, DriveCommand.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,  # 6
    (DriveState.READY_TO_SWITCH_ON, DriveCommand.QUICK_STOP): DriveState.SWITCH_ON_DISABLED,  # 7
    (DriveState.READY_TO_SWITCH_ON, DriveCommand.DISABLE_VOLTAGE):
        DriveState.SWITCH_ON_DISABLED,  # 7
    (DriveState.OPERATION_ENABLED, DriveCommand.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,  # 8
    (DriveState.OPERATION_ENABLED, DriveCommand.DISABLE_VOLTAGE):
        DriveState.SWITCH_ON_DISABLED,  # 9
    (DriveState.SWITCHED_ON, DriveCommand.DISABLE_VOLTAGE): DriveState.SWITCH_ON_DISABLED,  # 10
    (DriveState.SWITCHED_ON, DriveCommand.QUICK_STOP): DriveState.SWITCH_ON_DISABLED,  # 10
    (DriveState.OPERATION_ENABLED, DriveCommand.QUICK_STOP): DriveState.QUICK_STOP_ACTIVE,  # 11
    (DriveState.QUICK_STOP_ACTIVE, DriveCommand.DISABLE_VOLTAGE):
        DriveState.SWITCH_ON_DISABLED,  # 12
    (DriveState.FAULT, DriveCommand.FAULT_RESET): DriveState.SWITCH_ON_DISABLED,  # 15
    (DriveState.QUICK_STOP_ACTIVE, DriveCommand.ENABLE_OPERATION):
        DriveState.OPERATION_ENABLED,  # 16
})
"""What a command does in a state; absent pairs are ignored (the state stays)."""

AUTOMATIC_TRANSITIONS: Final[Mapping[DriveState, DriveState]] = MappingProxyType({
    DriveState.NOT_READY_TO_SWITCH_ON: DriveState.SWITCH_ON_DISABLED,  # 1: self-test done
    DriveState.FAULT_REACTION_ACTIVE: DriveState.FAULT,  # 14: fault reaction done
})
"""Transitions a drive makes by itself, once the state's work is done."""

# Bring-up takes every step explicitly: never 3+4 in one command, and never
# straight from a quick stop back to operation (16).
_NOT_FOR_BRING_UP: Final = frozenset({
    (DriveState.READY_TO_SWITCH_ON, DriveCommand.ENABLE_OPERATION),
    (DriveState.QUICK_STOP_ACTIVE, DriveCommand.ENABLE_OPERATION),
})


def next_state(state: DriveState, command: DriveCommand | None) -> DriveState:
    """The state after ``command`` (None = no command) per :data:`TRANSITIONS`."""
    if command is None:
        return state
    return TRANSITIONS.get((state, command), state)


def settle(state: DriveState) -> DriveState:
    """The state a drive reaches from ``state`` by automatic transitions alone."""
    while state in AUTOMATIC_TRANSITIONS:
        state = AUTOMATIC_TRANSITIONS[state]
    return state


def on_fault(state: DriveState) -> DriveState:
    """Transition 13: a fault sends every state but the fault states to FAULT_REACTION_ACTIVE."""
    if state in (DriveState.FAULT_REACTION_ACTIVE, DriveState.FAULT):
        return state
    return DriveState.FAULT_REACTION_ACTIVE


def _bring_up_paths() -> dict[DriveState, tuple[DriveCommand, ...]]:
    """Shortest command sequences to OPERATION_ENABLED, searched backwards from it."""
    paths: dict[DriveState, tuple[DriveCommand, ...]] = {DriveState.OPERATION_ENABLED: ()}
    frontier = [DriveState.OPERATION_ENABLED]
    while frontier:
        reached = []
        for (source, command), target in TRANSITIONS.items():
            usable = (source, command) not in _NOT_FOR_BRING_UP
            if usable and target in frontier and source not in paths:
                paths[source] = (command, *paths[target])
                reached.append(source)
        frontier = reached
    return paths


_BRING_UP_PATHS: Final = MappingProxyType(_bring_up_paths())


def path_to_enabled(state: DriveState) -> list[DriveCommand]:
    """The commands that bring a drive from ``state`` to OPERATION_ENABLED, in order.

    From NOT_READY_TO_SWITCH_ON and FAULT_REACTION_ACTIVE the drive first moves
    on by itself (:func:`settle`); wait for that before sending the first one.
    """
    return list(_BRING_UP_PATHS[settle(state)])
