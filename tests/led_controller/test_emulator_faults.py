"""Random link faults (``led_controller.emulator_faults``), drawn on the emulator's own frames."""

from __future__ import annotations

import time

import pytest

from msflash.led_controller import BoothEmulator
from msflash.led_controller.emulator_faults import FaultInjector, FaultRate, parse_fault_spec
from msflash.led_controller.protocol import encode_request, frame_problem


def _replies(rates: tuple[FaultRate, ...], seed: int, requests: int = 40, after: int = 0) -> list[bytes]:
    emulator = BoothEmulator()
    out: list[bytes] = []
    emulator.connect_output(out.append)
    FaultInjector(emulator, rates, seed=seed, after=after)
    for seq in range(1, requests + 1):
        emulator.receive(encode_request(seq, "PING"))
    return out


def test_the_same_seed_gives_the_same_faults_and_another_seed_others() -> None:
    rates = parse_fault_spec("drop:0.3,flip:0.3")
    first, again, other = _replies(rates, 7), _replies(rates, 7), _replies(rates, 8)
    assert first == again
    assert first != other
    damaged = [line for line in first if frame_problem(line.rstrip(b"\n")) is not None]
    assert 0 < len(damaged) < len(first)


def test_no_fault_before_the_first_after_requests() -> None:
    replies = _replies(parse_fault_spec("flip:1"), 0, requests=6, after=4)
    assert [frame_problem(line.rstrip(b"\n")) is None for line in replies] == [True] * 4 + [False] * 2


def test_a_stall_loses_its_request_and_answers_nothing_more() -> None:
    emulator = BoothEmulator()
    out: list[bytes] = []
    emulator.connect_output(out.append)
    injector = FaultInjector(emulator, parse_fault_spec("stall:1"), after=1)
    emulator.receive(encode_request(1, "SET", *["FFFF"] * 7))
    emulator.receive(encode_request(2, "OFF"))  # lost with the stalled booth: the LEDs stay on
    emulator.receive(encode_request(3, "OFF"))
    assert len(out) == 1 and emulator.levels == (1.0,) * 7
    assert emulator.snapshot()["stalled"] is True and injector.injected["stall"] == 1


def test_a_close_hangs_up_before_the_request_is_read() -> None:
    emulator = BoothEmulator()
    emulator.connect_output(lambda _data: None)
    FaultInjector(emulator, parse_fault_spec("close:1"))
    emulator.receive(encode_request(1, "SET", *["FFFF"] * 7))
    assert emulator.hangup_requested.is_set() and emulator.levels == (0.0,) * 7


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("drop:0.1,flip", "item 'flip': 0 value(s)"),
        ("flip:-0.1", "item 'flip:-0.1': probability -0.1 outside [0, 1]"),
        ("stall:0.1:inf", "item 'stall:0.1:inf': stall seconds 'inf' is not a finite number"),
        ("close:0.1:2", "item 'close:0.1:2': 2 value(s)"),
        ("drip:0.1", "item 'drip:0.1': kind 'drip' unknown"),
    ],
)
def test_a_bad_item_is_named(spec: str, says: str) -> None:
    with pytest.raises(
        ValueError,
        match=f"^--fault {says}".replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]"),
    ):
        parse_fault_spec(spec)


def test_a_stall_with_seconds_ends_by_itself() -> None:
    emulator = BoothEmulator()
    emulator.connect_output(lambda _data: None)
    FaultInjector(emulator, parse_fault_spec("stall:1:0.05"))
    emulator.receive(encode_request(1, "PING"))
    assert emulator.snapshot()["stalled"] is True
    deadline = time.monotonic() + 30.0
    while emulator.snapshot()["stalled"] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert emulator.snapshot()["stalled"] is False
