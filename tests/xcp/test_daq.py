"""DAQ with pyxcp's DAQ processor: lists on the 1 ms, 10 ms and engine events, timestamps in
µs of the ECU's clock, the values the ECU had at that tick; DAQ configuration errors."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from pyxcp.config import set_application
from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
from pyxcp.types import XcpResponseError

from tests.xcp.sim import XcpSim, master_config
from vecu.assembly import PRIO_ECU, TICK_NS


class Collect(DaqOnlinePolicy):
    """pyxcp's online DAQ policy keeping every sample: (list, slave timestamp, values)."""

    def __init__(self, lists: list[DaqList]) -> None:
        # pyxcp's DAQ processor reads the global application (else it parses sys.argv)
        set_application(master_config())
        super().__init__(lists)
        self.rows: list[tuple[int, int, list]] = []

    def initialize(self) -> None:
        pass

    def finalize(self) -> None:
        pass

    def on_daq_list(self, daq_list: int, timestamp0: int, timestamp1: int, payload: list) -> None:
        self.rows.append((daq_list, timestamp1, list(payload)))


def _addr(sim: XcpSim, name: str) -> int:
    return next(m for m in sim.xcp.measurements if m.name == name).address


def _wait(sim: XcpSim, sim_ms: int) -> None:
    end = sim.t_ns + sim_ms * TICK_NS
    while sim.t_ns < end:
        time.sleep(0.001)


@pytest.mark.alone  # the master's thread against the ECU's ticks: no other test beside it
def test_daq_samples_the_throttle_estimate_every_tick_with_timestamps():
    sim = XcpSim()
    truth: dict[int, float] = {}  # the ECU's estimate after each tick
    est = sim.fns.throttle.estimator
    sim.sched.every(TICK_NS, lambda t: truth.__setitem__(t, est.theta_deg), name="truth",
                    priority=PRIO_ECU + 1)
    lists = [
        DaqList("fast", 0, False, True, [
            ("throttle.estimate_deg", _addr(sim, "throttle.estimate_deg"), 0, "F32"),
            ("monitor.tps.status", _addr(sim, "monitor.tps.status"), 0, "U8")]),
        DaqList("slow", 2, False, True, [
            ("throttle.sigma_deg", _addr(sim, "throttle.sigma_deg"), 0, "F32"),
            ("speed.speed_mps", _addr(sim, "speed.speed_mps"), 0, "F32"),
            ("rx.accepted", _addr(sim, "rx.accepted"), 0, "U32")]),
        DaqList("engine", 4, False, True, [
            ("manifold.p_im_kpa", _addr(sim, "manifold.p_im_kpa"), 0, "F32")]),
    ]
    daq = Collect(lists)
    try:
        def work(m):
            m.connect()
            daq.setup()
            daq.start()
            t0 = sim.t_ns
            _wait(sim, 500)
            daq.stop()
            t1 = sim.t_ns
            return t0, t1

        t0, t1 = sim.serve(work, policy=daq)
    finally:
        sim.close()
    fast = [r for r in daq.rows if r[0] == 0]
    slow = [r for r in daq.rows if r[0] == 1]
    engine = [r for r in daq.rows if r[0] == 2]
    ticks = (t1 - t0) // TICK_NS
    assert len(fast) >= ticks - 5  # one sample per 1 ms tick, none lost
    assert sim.xcp.daq.stats.odts_lost == 0
    stamps = [ts for _, ts, _ in fast]
    # the slave's timestamps (µs, scaled to ns by pyxcp) step by exactly one tick
    assert all(b - a == TICK_NS for a, b in itertools.pairwise(stamps))
    names = [name for name, _ in lists[0].headers]  # pyxcp orders a list's entries
    rows = [dict(zip(names, payload)) for _, _, payload in fast]
    # pyxcp gives timestamps from the first sample: find that sample's tick by its value,
    # then every later sample is the ECU's value of its tick (as FLOAT32_IEEE)
    first = rows[0]["throttle.estimate_deg"]
    starts = [t for t in sorted(truth) if t0 - 50 * TICK_NS <= t <= t0 + 20 * TICK_NS
              and np.float32(truth[t]) == np.float32(first)]
    assert starts, "the first sample is none of the ECU's values"
    start = starts[0]
    for (_, ts, _), row in zip(fast, rows):
        assert row["throttle.estimate_deg"] == np.float32(truth[start + ts])
        assert row["monitor.tps.status"] == 0
    slow_stamps = [ts for _, ts, _ in slow]
    assert slow_stamps and all(b - a == 10 * TICK_NS for a, b in itertools.pairwise(slow_stamps))
    assert len(slow) == pytest.approx(len(fast) / 10, abs=2)
    assert engine and all(10.0 < row[2][0] < 110.0 for row in engine)  # kPa


def test_daq_configuration_errors():
    sim = XcpSim()
    try:
        def work(m):
            m.connect()
            errs = {}

            def err(name, fn, *args):
                try:
                    fn(*args)
                except XcpResponseError as exc:
                    errs[name] = str(exc.get_error_code())
                else:
                    errs[name] = "accepted"

            m.freeDaq()
            err("odt_before_daq", m.allocOdt, 0, 1)
            err("too_many_lists", m.allocDaq, 1000)
            m.allocDaq(1)
            err("no_such_list", m.allocOdt, 5, 1)
            m.allocOdt(0, 1)
            m.allocOdtEntry(0, 0, 2)
            m.setDaqPtr(0, 0, 0)
            err("unmapped", m.writeDaq, 0xFF, 4, 0, 0x0500_0000)
            err("bit_daq", m.writeDaq, 3, 1, 0, _addr(sim, "monitor.tps.status"))
            m.writeDaq(0xFF, 4, 0, _addr(sim, "rx.accepted"))
            err("odt_too_big", m.writeDaq, 0xFF, 4, 0, _addr(sim, "rx.received"))
            err("bad_event", m.setDaqListMode, 0x10, 0, 99, 1, 0)
            err("stim", m.setDaqListMode, 0x02, 0, 0, 1, 0)
            err("unconfigured", m.startStopDaqList, 1, 0)  # no event set yet
            info = m.getDaqListInfo(0)
            errs["list_info"] = (info.maxOdt, info.maxOdtEntries, info.daqListProperties.daq,
                                 info.daqListProperties.predefined)
            m.setDaqListMode(0x00, 0, 0, 1, 0)
            err("empty_entry", m.startStopDaqList, 1, 0)  # the second entry is not written
            return errs

        errs = sim.serve(work)
    finally:
        sim.close()
    assert errs == {"odt_before_daq": "ERR_SEQUENCE", "too_many_lists": "ERR_MEMORY_OVERFLOW",
                    "no_such_list": "ERR_OUT_OF_RANGE", "unmapped": "ERR_ACCESS_DENIED",
                    "bit_daq": "ERR_OUT_OF_RANGE", "odt_too_big": "ERR_DAQ_CONFIG",
                    "bad_event": "ERR_OUT_OF_RANGE", "stim": "ERR_MODE_NOT_VALID",
                    "unconfigured": "ERR_DAQ_CONFIG", "empty_entry": "ERR_DAQ_CONFIG",
                    "list_info": (1, 2, True, False)}
