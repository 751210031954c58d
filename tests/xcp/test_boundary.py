"""Nothing an XCP master sends stops the ECU: the eleven frames that killed it (a DAQ entry in
the GET_ID area, then GET_ID / GET_DAQ_EVENT_INFO shortening that area) as raw frames on the
simulated clock, the DAQ sampler and the command handler behind the slave's boundary, and
measurement values their type cannot hold (saturated and counted)."""

from __future__ import annotations

import logging
import math
import struct

import pytest

from tests.xcp.sim import RawMaster, XcpSim
from vecu.xcp.config import XcpConfig
from vecu.xcp.daq import Daq
from vecu.xcp.measurements import Measurement
from vecu.xcp.memory import ID_BASE

CONNECT = bytes([0xFF, 0x00])
GET_STATUS = bytes([0xFD])


def eleven_frames(last: bytes) -> list[bytes]:
    """The issue's sequence: CONNECT, GET_ID 0, one DAQ list of one 4-byte entry at
    0x00F00008 (inside the GET_ID text, readable then) on the 1 ms event, started; `last`
    then shortens the GET_ID area (GET_ID 1, or GET_DAQ_EVENT_INFO 0)."""
    return [CONNECT, bytes([0xFA, 0x00]), bytes([0xD6]), bytes([0xD5, 0, 1, 0]),
            bytes([0xD4, 0, 0, 0, 1]), bytes([0xD3, 0, 0, 0, 0, 1]), bytes([0xE2, 0, 0, 0, 0, 0]),
            bytes([0xE1, 0xFF, 4, 0]) + struct.pack("<I", ID_BASE + 8),
            bytes([0xE0, 0x00, 0, 0, 0, 0, 1, 0]), bytes([0xDE, 0x01, 0, 0]), last]


@pytest.mark.parametrize("last", [bytes([0xFA, 0x01]), bytes([0xD7, 0x00, 0x00, 0x00])],
                         ids=["GET_ID_1", "GET_DAQ_EVENT_INFO_0"])
def test_the_eleven_frames_leave_the_ecu_broadcasting_and_answering(last):
    sim = XcpSim()
    try:
        raw = RawMaster(sim)
        raw.step(50)
        answers = [raw.ask(cto) for cto in eleven_frames(last)]
        raw.estimates.clear()
        after = raw.step(200)
        estimates = list(raw.estimates)
        connect, status = raw.ask(CONNECT), raw.ask(GET_STATUS)
    finally:
        sim.close()
    assert all(len(a) == 1 for a in answers), answers  # one answer to each command
    # the GET_ID area is not measurable: WRITE_DAQ refused (ERR_ACCESS_DENIED), the list
    # with its entry unwritten cannot start (ERR_DAQ_CONFIG)
    assert answers[7] == [bytes([0xFE, 0x24])] and answers[9] == [bytes([0xFE, 0x2A])]
    assert answers[10][0][0] == 0xFF
    assert after == []  # no DTO, no error packet
    # 200 more ticks, one estimate each, decoded from the bus and in range
    assert len(estimates) == 200
    assert all(0.0 <= e["THR_AngleEst"] <= 90.0 for e in estimates)
    assert connect == [bytes([0xFF, 0x15, 0xC0, 8, 8, 0, 1, 1])]
    assert status == [bytes([0xFF, 0x00, 0x00, 0, 0, 0])]  # no DAQ running, nothing locked
    assert sim.xcp.boundary.counts == {}  # refused by the protocol, not caught as a fault


def test_a_daq_entry_that_cannot_be_read_drops_its_dto_and_the_rest_go_on(caplog):
    """The sampler's boundary: an entry whose read raises loses its DTO (counted, logged once
    per kind); the list's other ODTs and the other lists are still sent."""
    daq = Daq(XcpConfig())
    errors: list[Exception] = []
    daq.on_read_error = errors.append

    def reader(address: int, size: int, ext: int):
        if address == 0xBAD:
            return lambda: struct.pack("<I", 1 << 40)  # struct.error: out of range for "I"
        return lambda: bytes(size)

    daq.reader = reader
    cmds = daq.commands()
    for cto in ([0xD6], [0xD5, 0, 2, 0], [0xD4, 0, 0, 0, 2], [0xD4, 0, 1, 0, 1],
                [0xD3, 0, 0, 0, 0, 1], [0xD3, 0, 0, 0, 1, 1], [0xD3, 0, 1, 0, 0, 1],
                [0xE2, 0, 0, 0, 0, 0], [0xE1, 0xFF, 4, 0, 0xAD, 0x0B, 0, 0],
                [0xE2, 0, 0, 0, 1, 0], [0xE1, 0xFF, 2, 0, 0, 0, 0x10, 0],
                [0xE2, 0, 1, 0, 0, 0], [0xE1, 0xFF, 1, 0, 0, 0, 0x10, 0],
                [0xE0, 0, 0, 0, 0, 0, 1, 0], [0xE0, 0, 1, 0, 0, 0, 1, 0],
                [0xDE, 1, 0, 0], [0xDE, 1, 1, 0]):
        cmds[cto[0]](bytes(cto))
    sent: list[bytes] = []
    for t in range(1, 4):
        daq.sample(t * 1_000_000, False, lambda dto: sent.append(dto) or True)
    assert daq.stats.odts_dropped == 3 and len(errors) == 3
    assert sorted(dto[0] for dto in sent) == [1, 1, 1, 2, 2, 2]  # ODT 1 of list 0, list 1
    assert daq.stats.odts_sent == 6


def test_a_handler_fault_answers_err_generic_logs_once_and_the_node_ticks(caplog):
    """A handler that raises what it should not (a bug, injected here) answers ERR_GENERIC,
    is counted per kind and logged once, and the ECU goes on."""
    sim = XcpSim()
    try:
        raw = RawMaster(sim)
        raw.ask(CONNECT)

        def broken(cto: bytes) -> bytes:
            raise ZeroDivisionError("injected")

        sim.xcp.proc._cmds[0xF1] = broken  # USER_CMD: a handler bug
        raw.estimates.clear()
        with caplog.at_level(logging.ERROR, logger="vecu.xcp.server"):
            answers = [raw.ask(bytes([0xF1, 0, 0])) for _ in range(3)]
        status = raw.ask(GET_STATUS)
        summary = sim.xcp.summary()
    finally:
        sim.close()
    assert answers == [[bytes([0xFE, 0x31])]] * 3
    assert status == [bytes([0xFF, 0, 0, 0, 0, 0])]
    assert len(raw.estimates) == 4
    assert summary["internal_errors"] == {"command 0xF1: ZeroDivisionError": 3}
    assert len([r for r in caplog.records if "ZeroDivisionError" in r.getMessage()]) == 1


@pytest.mark.parametrize(("code", "value", "expect"), [
    ("f", 1e39, struct.pack("<f", 3.4028234663852886e38)),
    ("f", -1e300, struct.pack("<f", -3.4028234663852886e38)),
    ("f", 10 ** 400, struct.pack("<f", 3.4028234663852886e38)),
    ("B", math.nan, b"\x00"), ("B", math.inf, b"\xff"), ("B", 300, b"\xff"), ("B", -1, b"\x00"),
    ("I", 1 << 40, b"\xff\xff\xff\xff"), ("I", -math.inf, b"\x00\x00\x00\x00"),
])
def test_a_value_its_type_cannot_hold_is_saturated_and_counted(code, value, expect):
    m = Measurement("x", "1", code, lambda: value, 0, 1, "")
    assert m.pack() == expect and m.stats.saturated == 1


@pytest.mark.parametrize(("code", "value"), [("f", math.nan), ("f", math.inf), ("f", 2.5),
                                             ("B", None), ("B", 255), ("I", 0), ("B", True)])
def test_a_value_that_fits_is_packed_as_it_is(code, value):
    m = Measurement("x", "1", code, lambda: value, 0, 1, "")
    expected = struct.pack("<" + code, math.nan if value is None and code == "f"
                           else (0 if value is None else value))
    assert m.pack() == expected and m.stats.saturated == 0
