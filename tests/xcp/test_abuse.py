"""A bounded abuse run of the XCP slave on the simulated clock, as raw frames: every command
code at every length 1..8 with edge values (address 0, 0xFFFFFFFF, the edges of the
measurement area, the calibration segment and the GET_ID area; sizes and modes 0, 1, 7, 0xFF),
then DAQ set-up sequences in seeded random orders. Afterwards: nothing raised out of the tick
(the scheduler would re-raise it), nothing needed the slave's fault boundary (every refusal was
a protocol answer), the ECU broadcast its throttle estimate on every tick, and the slave still
answers CONNECT and GET_STATUS exactly."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import numpy as np
import pytest

from tests.xcp.sim import RawMaster, XcpSim
from vecu.config import RunConfig
from vecu.xcp.daq import EVENTS
from vecu.xcp.memory import CAL_BASE, ID_BASE, MEAS_BASE

CONNECT = bytes([0xFF, 0x00])
CONNECTED = bytes([0xFF, 0x15, 0xC0, 8, 8, 0, 1, 1])


def edge_addresses(sim: XcpSim) -> list[int]:
    meas_end = sim.xcp.proc.meas_end
    cal_end = CAL_BASE + sim.xcp.segment.size
    return [0, 0xFFFFFFFF, MEAS_BASE - 1, MEAS_BASE, meas_end - 4, meas_end - 1, meas_end,
            CAL_BASE, cal_end - 8, cal_end - 1, cal_end, ID_BASE, ID_BASE + 8]


def every_command(sim: XcpSim) -> Iterator[bytes]:
    """Each code 0x00..0xFF at each length 1..8 (all 0x00, all 0xFF), and at length 8 with
    each edge address in bytes 4..7 and each edge size / mode in byte 1."""
    addresses = edge_addresses(sim)
    for code in range(256):
        for length in range(1, 9):
            yield bytes([code]) + bytes(length - 1)
            yield bytes([code]) + b"\xff" * (length - 1)
        for size in (0, 1, 7, 0xFF):
            for address in addresses:
                yield bytes([code, size, 0, 0]) + struct.pack("<I", address)


def daq_command(rng: np.random.Generator, addresses: list[int]) -> bytes:
    """One DAQ command (or a command that changes the MTA / GET_ID area, or the session)
    with small random parameters, valid or not."""
    lst = int(rng.integers(0, 4))
    kind = int(rng.integers(0, 17))
    if kind == 0:
        return bytes([0xD6])                                               # FREE_DAQ
    if kind == 1:
        return bytes([0xD5, 0]) + struct.pack("<H", int(rng.integers(0, 4)))  # ALLOC_DAQ
    if kind == 2:
        return bytes([0xD4, 0]) + struct.pack("<HB", lst, int(rng.integers(0, 4)))
    if kind == 3:
        return bytes([0xD3, 0]) + struct.pack("<HBB", lst, int(rng.integers(0, 4)),
                                              int(rng.integers(0, 9)))
    if kind == 4:
        return bytes([0xE2, 0]) + struct.pack("<HBB", lst, int(rng.integers(0, 4)),
                                              int(rng.integers(0, 8)))
    if kind in (5, 6):                                                     # WRITE_DAQ
        bit = 0xFF if rng.random() < 0.9 else int(rng.integers(0, 256))
        return bytes([0xE1, bit, int(rng.integers(0, 9)), int(rng.random() < 0.05)]) + \
            struct.pack("<I", addresses[int(rng.integers(0, len(addresses)))])
    if kind == 7:                                                          # SET_DAQ_LIST_MODE
        mode = int(rng.choice([0x00, 0x10, 0x10, 0x02, 0x20, int(rng.integers(0, 256))]))
        return bytes([0xE0, mode]) + struct.pack("<HHBB", lst, int(rng.integers(0, len(EVENTS) + 1)),
                                                 int(rng.integers(0, 3)), 0)
    if kind in (8, 9):                                                     # START_STOP_DAQ_LIST
        return bytes([0xDE, int(rng.integers(0, 4))]) + struct.pack("<H", lst)
    if kind == 10:
        return bytes([0xDD, int(rng.integers(0, 5))])                      # START_STOP_SYNCH
    if kind == 11:
        return bytes([0xE3, 0]) + struct.pack("<H", lst)                   # CLEAR_DAQ_LIST
    if kind == 12:
        return bytes([0xFA, int(rng.choice([0, 1, 4, 7]))])                # GET_ID
    if kind == 13:
        return bytes([0xD7, 0]) + struct.pack("<H", int(rng.integers(0, len(EVENTS) + 1)))
    if kind == 14:
        return bytes([int(rng.choice([0xDF, 0xD8])), 0]) + struct.pack("<H", lst)
    if kind == 15:
        return bytes([0xFD])                                               # GET_STATUS
    return bytes([0xFE]) if rng.random() < 0.2 else CONNECT               # DISCONNECT


def daq_setup(rng: np.random.Generator, addresses: list[int]) -> list[bytes]:
    """A whole set-up (FREE .. start), its entries at random addresses (often valid ones)."""
    n = int(rng.integers(1, 4))
    out = [bytes([0xD6]), bytes([0xD5, 0]) + struct.pack("<H", 1),
           bytes([0xD4, 0, 0, 0, 1]), bytes([0xD3, 0, 0, 0, 0, n]), bytes([0xE2, 0, 0, 0, 0, 0])]
    for _ in range(n):
        out.append(bytes([0xE1, 0xFF, int(rng.choice([1, 2])), 0]) +
                   struct.pack("<I", addresses[int(rng.integers(0, len(addresses)))]))
    out += [bytes([0xE0, 0x00, 0, 0]) + struct.pack("<HBB", int(rng.integers(0, len(EVENTS))), 1, 0),
            bytes([0xDE, 0x01, 0, 0])]
    return out


def run_frames(raw: RawMaster, frames: Iterator[bytes], per_tick: int) -> int:
    """Each tick: CONNECT, then per_tick - 1 frames (within commands_per_tick); the ticks."""
    ticks = 0
    batch: list[bytes] = []
    for cto in frames:
        batch.append(cto)
        if len(batch) == per_tick - 1:
            raw.send(CONNECT, *batch)
            raw.step()
            ticks += 1
            batch = []
    if batch:
        raw.send(CONNECT, *batch)
        raw.step()
        ticks += 1
    return ticks


def check_alive(sim: XcpSim, raw: RawMaster) -> None:
    """The slave answers CONNECT and GET_STATUS exactly, and stops DAQ on request."""
    raw.step(2)
    assert raw.ask(CONNECT) == [CONNECTED]
    running = sim.xcp.daq.running
    locked = sim.xcp.proc.security.locked  # 0, or every resource after CONNECT (seed & key)
    assert locked == (0x15 if sim.config.params.ecu.xcp.seed_key else 0)
    status = [p for p in raw.ask(bytes([0xFD])) if p[0] >= 0xFC]  # DTOs may come too
    assert status == [bytes([0xFF, 0x40 if running else 0, locked, 0, 0, 0])]
    if not locked:
        assert [p for p in raw.ask(bytes([0xDD, 0])) if p[0] >= 0xFC] == [b"\xff"]  # stop all
        assert raw.ask(bytes([0xFD])) == [bytes([0xFF, 0, 0, 0, 0, 0])]
    assert sim.xcp.boundary.counts == {}


@pytest.fixture
def sim():
    s = XcpSim()
    yield s
    s.close()


@pytest.mark.parametrize("seed_key", [False, True])
def test_every_command_at_every_length_and_edge_leaves_the_ecu_ticking(seed_key):
    config = RunConfig(duration_s=600.0, kill_tps_at_s=None).with_params(
        [("ecu.xcp.seed_key", str(seed_key).lower())])
    sim = XcpSim(config)
    try:
        sweep(sim)
    finally:
        sim.close()


def sweep(sim: XcpSim) -> None:
    raw = RawMaster(sim)
    raw.step(20)
    raw.estimates.clear()
    per_tick = sim.config.params.ecu.xcp.commands_per_tick
    ticks = run_frames(raw, every_command(sim), per_tick)
    assert ticks > 1500
    assert len(raw.estimates) == ticks  # the broadcast on every tick
    assert sim.xcp.proc.stats.commands > 14_000 and sim.xcp.frames_dropped == 0
    check_alive(sim, raw)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_daq_set_up_sequences_in_random_orders_leave_the_ecu_ticking(sim, seed):
    rng = np.random.default_rng(seed)
    raw = RawMaster(sim)
    raw.step(20)
    raw.estimates.clear()
    addresses = ([m.address for m in sim.xcp.measurements] * 3 + edge_addresses(sim)
                 + [m.address + 1 for m in sim.xcp.measurements[:4]])
    per_tick = sim.config.params.ecu.xcp.commands_per_tick

    def frames() -> Iterator[bytes]:
        for _ in range(3000):
            if rng.random() < 0.05:
                yield from daq_setup(rng, addresses)
            else:
                yield daq_command(rng, addresses)

    ticks = run_frames(raw, frames(), per_tick)
    assert len(raw.estimates) == ticks
    stats = sim.xcp.daq.stats
    assert stats.odts_sent > 0  # lists ran and were sampled
    check_alive(sim, raw)
