"""The CiA 402 table against the standard's tables, and a scripted bring-up over codec frames."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rakectl.errors import FrameError
from rakectl.protocol import cia402, codec
from rakectl.protocol.cia402 import DriveCommand, DriveState, StatusFlag

S, C = DriveState, DriveCommand

# The state machine figure of CiA 402 / IEC 61800-7-201, transcribed independently
# of the module: (number, from, command, to). 3+4 is "switch on + enable operation".
STANDARD_FIGURE = [
    (2, S.SWITCH_ON_DISABLED, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    (3, S.READY_TO_SWITCH_ON, C.SWITCH_ON, S.SWITCHED_ON),
    (34, S.READY_TO_SWITCH_ON, C.ENABLE_OPERATION, S.OPERATION_ENABLED),
    (4, S.SWITCHED_ON, C.ENABLE_OPERATION, S.OPERATION_ENABLED),
    (5, S.OPERATION_ENABLED, C.DISABLE_OPERATION, S.SWITCHED_ON),
    (6, S.SWITCHED_ON, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    (7, S.READY_TO_SWITCH_ON, C.QUICK_STOP, S.SWITCH_ON_DISABLED),
    (7, S.READY_TO_SWITCH_ON, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (8, S.OPERATION_ENABLED, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    (9, S.OPERATION_ENABLED, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, C.QUICK_STOP, S.SWITCH_ON_DISABLED),
    (11, S.OPERATION_ENABLED, C.QUICK_STOP, S.QUICK_STOP_ACTIVE),
    (12, S.QUICK_STOP_ACTIVE, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (15, S.FAULT, C.FAULT_RESET, S.SWITCH_ON_DISABLED),
    (16, S.QUICK_STOP_ACTIVE, C.ENABLE_OPERATION, S.OPERATION_ENABLED),
]

# Statusword table: the standard's value with every don't-care bit set, and with none.
STATUSWORDS = {
    S.NOT_READY_TO_SWITCH_ON: (0b0000_0000, 0b1011_0000),
    S.SWITCH_ON_DISABLED: (0b0100_0000, 0b1111_0000),
    S.READY_TO_SWITCH_ON: (0b0010_0001, 0b1011_0001),
    S.SWITCHED_ON: (0b0010_0011, 0b1011_0011),
    S.OPERATION_ENABLED: (0b0010_0111, 0b1011_0111),
    S.QUICK_STOP_ACTIVE: (0b0000_0111, 0b1001_0111),
    S.FAULT_REACTION_ACTIVE: (0b0000_1111, 0b1011_1111),
    S.FAULT: (0b0000_1000, 0b1011_1000),
}

# Controlword table: (command, bits 7..0 with x) per the standard.
CONTROLWORDS = [
    (C.SHUTDOWN, "0xxxx110"),
    (C.SWITCH_ON, "0xxx0111"),
    (C.ENABLE_OPERATION, "0xxx1111"),
    (C.DISABLE_VOLTAGE, "0xxxxx0x"),
    (C.QUICK_STOP, "0xxxx01x"),
    (C.DISABLE_OPERATION, "0xxx0111"),
]


def _matches(word: int, pattern: str) -> bool:
    bits = format(word & 0xFF, "08b")
    return all(p in ("x", b) for p, b in zip(pattern, bits, strict=True))


# --------------------------------------------------------------------------- table


def test_transition_table_is_the_standards_figure() -> None:
    expected = {(source, command): target for _, source, command, target in STANDARD_FIGURE}
    assert dict(cia402.TRANSITIONS) == expected


def test_automatic_transitions_are_1_and_14() -> None:
    assert dict(cia402.AUTOMATIC_TRANSITIONS) == {
        S.NOT_READY_TO_SWITCH_ON: S.SWITCH_ON_DISABLED,
        S.FAULT_REACTION_ACTIVE: S.FAULT,
    }
    assert cia402.settle(S.FAULT_REACTION_ACTIVE) is S.FAULT
    assert cia402.settle(S.OPERATION_ENABLED) is S.OPERATION_ENABLED


@pytest.mark.parametrize("state", list(DriveState))
@pytest.mark.parametrize("command", list(DriveCommand))
def test_commands_outside_the_table_are_ignored(state: DriveState, command: DriveCommand) -> None:
    expected = cia402.TRANSITIONS.get((state, command), state)
    assert cia402.next_state(state, command) is expected
    assert cia402.next_state(state, None) is state


@pytest.mark.parametrize("state", list(DriveState))
def test_a_fault_leads_to_fault_reaction_from_any_state(state: DriveState) -> None:
    faulted = cia402.on_fault(state)
    if state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
        assert faulted is state
    else:
        assert faulted is S.FAULT_REACTION_ACTIVE


def test_disable_operation_is_switch_on_on_the_wire() -> None:
    assert C.DISABLE_OPERATION is C.SWITCH_ON
    assert cia402.controlword(C.DISABLE_OPERATION) == 0x0007


# --------------------------------------------------------------------------- statusword


@pytest.mark.parametrize("state", list(DriveState))
def test_statusword_of_every_state_decodes(state: DriveState) -> None:
    for statusword in STATUSWORDS[state]:
        assert cia402.decode_statusword(statusword) is state
        assert cia402.decode_statusword(statusword | 0xFF00) is state


@given(st.sampled_from(DriveState), st.integers(0, 0xFFFF))
def test_statusword_round_trip_with_any_flags(state: DriveState, bits: int) -> None:
    flags = StatusFlag(bits) & (StatusFlag.VOLTAGE_ENABLED | StatusFlag.WARNING
                                | StatusFlag.REMOTE | StatusFlag.TARGET_REACHED
                                | StatusFlag.INTERNAL_LIMIT_ACTIVE)
    statusword = cia402.encode_statusword(state, flags)
    assert cia402.decode_statusword(statusword) is state
    assert cia402.status_flags(statusword) == flags


def test_every_low_byte_decodes_to_at_most_one_state_or_is_rejected() -> None:
    for low in range(0x80):
        owners = [s for s, (lo, hi) in STATUSWORDS.items() if (low & ~(lo ^ hi)) == lo]
        if owners:
            assert cia402.decode_statusword(low) is owners[0]
            assert len(owners) == 1
        else:
            with pytest.raises(FrameError, match="is no CiA 402 state"):
                cia402.decode_statusword(low)


def test_flags_may_not_touch_state_bits() -> None:
    with pytest.raises(FrameError):
        cia402.encode_statusword(S.FAULT, StatusFlag(0x0001))


@pytest.mark.parametrize("word", [-1, 0x10000])
def test_words_out_of_range_are_rejected(word: int) -> None:
    with pytest.raises(FrameError):
        cia402.decode_statusword(word)
    with pytest.raises(FrameError):
        cia402.decode_controlword(word, 0)


# --------------------------------------------------------------------------- controlword


@pytest.mark.parametrize(("command", "pattern"), CONTROLWORDS)
def test_controlword_of_each_command_fits_the_standards_pattern(
    command: DriveCommand, pattern: str
) -> None:
    assert _matches(cia402.controlword(command), pattern)
    assert cia402.decode_controlword(cia402.controlword(command), 0) is command


@given(st.integers(0, 0xFFFF).filter(lambda w: not w & 0x80), st.integers(0, 0xFFFF))
def test_any_controlword_without_bit_7_decodes_per_the_table(word: int, previous: int) -> None:
    command = cia402.decode_controlword(word, previous)
    fitting = {c for c, pattern in CONTROLWORDS if _matches(word, pattern)}
    assert fitting == {command}  # SWITCH_ON and DISABLE_OPERATION are one member


def test_fault_reset_acts_on_the_rising_edge_of_bit_7() -> None:
    reset = cia402.controlword(C.FAULT_RESET)
    assert cia402.decode_controlword(reset, previous_controlword=0x000F) is C.FAULT_RESET
    assert cia402.decode_controlword(reset, previous_controlword=reset) is None
    assert cia402.decode_controlword(0x008F, previous_controlword=0x0080) is None
    assert cia402.decode_controlword(0x0006, previous_controlword=reset) is C.SHUTDOWN


def test_held_fault_reset_does_not_leave_fault_twice() -> None:
    state, previous = S.FAULT, 0x000F
    for _ in range(3):
        command = cia402.decode_controlword(0x0080, previous)
        state, previous = cia402.next_state(state, command), 0x0080
        assert state is S.SWITCH_ON_DISABLED
    assert cia402.next_state(S.FAULT, cia402.decode_controlword(0x0080, 0x0080)) is S.FAULT


# --------------------------------------------------------------------------- bring-up


@pytest.mark.parametrize("state", list(DriveState))
def test_bring_up_path_reaches_operation_enabled_by_the_table(state: DriveState) -> None:
    path = cia402.path_to_enabled(state)
    current = cia402.settle(state)
    for command in path:
        assert (current, command) in cia402.TRANSITIONS
        current = cia402.TRANSITIONS[(current, command)]
    assert current is S.OPERATION_ENABLED


def test_bring_up_takes_every_step_explicitly() -> None:
    full = [C.SHUTDOWN, C.SWITCH_ON, C.ENABLE_OPERATION]
    assert cia402.path_to_enabled(S.SWITCH_ON_DISABLED) == full
    assert cia402.path_to_enabled(S.FAULT) == [C.FAULT_RESET, *full]
    assert cia402.path_to_enabled(S.QUICK_STOP_ACTIVE) == [C.DISABLE_VOLTAGE, *full]
    assert cia402.path_to_enabled(S.READY_TO_SWITCH_ON) == [C.SWITCH_ON, C.ENABLE_OPERATION]
    assert cia402.path_to_enabled(S.OPERATION_ENABLED) == []


class ScriptedDrive:
    """The drive's side of the state machine, fed RPDO1 frames, answering TPDO2 frames."""

    def __init__(self, state: DriveState) -> None:
        self.state, self.previous_controlword = state, 0

    def on_rpdo(self, frame: bytes) -> bytes:
        _, word = codec.decode_rpdo(frame)
        command = cia402.decode_controlword(word, self.previous_controlword)
        self.state = cia402.settle(cia402.next_state(self.state, command))
        self.previous_controlword = word
        flags = StatusFlag.REMOTE | (StatusFlag.VOLTAGE_ENABLED
                                     if self.state is S.OPERATION_ENABLED else StatusFlag(0))
        return codec.encode_tpdo2(cia402.encode_statusword(self.state, flags), 0)


@pytest.mark.parametrize("start", list(DriveState))
def test_scripted_bring_up_over_frames(start: DriveState) -> None:
    drive = ScriptedDrive(start)
    frame = drive.on_rpdo(codec.encode_rpdo(0, 0))
    sent = []
    for _ in range(10):
        statusword, _ = codec.decode_tpdo2(frame)
        path = cia402.path_to_enabled(cia402.decode_statusword(statusword))
        if not path:
            break
        sent.append(path[0])
        frame = drive.on_rpdo(codec.encode_rpdo(0, cia402.controlword(path[0])))
    assert drive.state is S.OPERATION_ENABLED
    assert len(sent) <= 4
