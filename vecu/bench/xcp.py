"""XCP: DAQ rate, lost ODTs, broadcast ticks kept and command latency (issue 31 item 4), live.

Plant, ECU with its XCP slave and a bare echo task on virtual channels, paced by a WallClock in
this process (as the live processes); pyxcp is the master on its own threads:

- command latency: SHORT_UPLOAD of a 4-byte measurement (send -> response), p50 / p99, against
  a bare echo served by a 1 ms task on the same clock and tick (one 8-byte frame in, the same
  frame out, on a channel of its own): the transport and tick quantisation without XCP;
- DAQ: one list on the 1 ms event (the throttle estimate, its sigma, the TPS status) for the
  window: samples/s at the master, ODTs lost (slave count and gaps in the slave's timestamps);
- broadcast ticks kept: ECU_ThrottleEstimate frames the ECU sent against its 1 ms releases in the
  DAQ window, and in an idle window of the same length after it (the baseline).
Needs pyxcp (`pip install pyxcp`, in vecu[test]).
"""

from __future__ import annotations

import gc
import itertools
import sys
import threading
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S, WallClock, perf_ns, sleep
from vecu.errors import UnavailableError

ECHO_ID, ECHO_REPLY_ID = 0x7F8, 0x7F9
SWITCH_INTERVAL_S = 0.0002
_channels = itertools.count()


def _stats(ns: list[int]) -> dict[str, float]:
    a = np.asarray(ns, dtype=float) / 1e6
    return {"n": len(ns), "p50_ms": round(float(np.percentile(a, 50)), 3),
            "p99_ms": round(float(np.percentile(a, 99)), 3), "max_ms": round(float(a.max()), 3)}


class _Rig:
    """Plant, ECU with its XCP slave, and the echo, on WallClock."""

    def __init__(self, duration_s: float) -> None:
        from vecu.assembly import (
            build_functions,
            build_plant,
            schedule_ecu,
            schedule_plant,
        )
        from vecu.bus import open_bus
        from vecu.codec import DbcCodec
        from vecu.config import RunConfig
        from vecu.ecu.node import EcuNode
        from vecu.live.options import DEFAULT_SPIN_US
        from vecu.runner import attach_xcp_server
        from vecu.scheduler import Scheduler

        self.config = RunConfig(duration_s=duration_s, kill_tps_at_s=None)
        codec = DbcCodec()
        self.channel = f"vecu-bench-xcp-{next(_channels)}-{perf_ns()}"
        self.buses = [open_bus("virtual", self.channel) for _ in range(3)] + [
            open_bus("virtual", self.channel + "-echo") for _ in range(2)]
        plant_bus, ecu_bus, self.master_bus, self.echo_bus, self.echo_client = self.buses
        self.fns = build_functions(self.config, codec)
        self.ecu = EcuNode(ecu_bus, codec, self.fns.enabled())
        xcp = attach_xcp_server(self.ecu, self.config)
        assert xcp is not None
        self.xcp = xcp
        self.clock = WallClock(spin_ns=DEFAULT_SPIN_US * 1000)
        self.sched = Scheduler(self.clock)
        schedule_plant(self.sched, build_plant(self.config, codec, plant_bus))
        self.ecu_task = schedule_ecu(self.sched, self.ecu)
        self.sched.every(NS_PER_MS, self._echo, name="echo", priority=15)  # after the ECU
        self.marks: list[tuple[int, int, int]] = []

    def _echo(self, t_ns: int) -> None:
        bus = self.echo_bus
        while (msg := bus.recv(0.0)) is not None:
            if msg.arbitration_id == ECHO_ID:
                msg.arbitration_id = ECHO_REPLY_ID
                msg.timestamp = t_ns / NS_PER_S
                bus.send(msg)

    def mark(self) -> None:
        task = self.ecu_task
        self.marks.append((perf_ns(), task.runs + task.skipped, self.fns.throttle.estimates_sent))

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()


def _master_work(rig: _Rig, commands: int, daq_s: float) -> dict[str, Any]:
    import can
    from pyxcp.config import set_application
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
    from pyxcp.master import Master

    from vecu.xcp.daq import TIMESTAMP_NS

    cfg = rig.config.params.ecu.xcp
    app = _pyxcp_app(cfg.master_id, cfg.slave_id, rig.channel)
    set_application(app)
    addr = {m.name: m.address for m in rig.xcp.measurements}

    class Collect(DaqOnlinePolicy):
        def __init__(self, lists: list) -> None:
            super().__init__(lists)
            self.stamps: list[int] = []

        def initialize(self) -> None:
            pass

        def finalize(self) -> None:
            pass

        def on_daq_list(self, daq_list: int, ts0: int, ts1: int, payload: list) -> None:
            self.stamps.append(ts1)

    daq = Collect([DaqList("throttle", 0, False, True, [
        ("throttle.estimate_deg", addr["throttle.estimate_deg"], 0, "F32"),
        ("throttle.sigma_deg", addr["throttle.sigma_deg"], 0, "F32"),
        ("monitor.tps.status", addr["monitor.tps.status"], 0, "U8")])])
    out: dict[str, Any] = {}
    with Master("can", config=app, policy=daq, transport_layer_interface=rig.master_bus) as m:
        m.connect()
        lat = []
        for _ in range(commands):
            t0 = perf_ns()
            m.shortUpload(4, addr["throttle.estimate_deg"])
            lat.append(perf_ns() - t0)
        out["command"] = _stats(lat)
        echo = []
        frame = can.Message(arbitration_id=ECHO_ID, data=bytes(8), is_extended_id=False)
        for _ in range(commands):
            t0 = perf_ns()
            rig.echo_client.send(frame)
            while True:
                reply = rig.echo_client.recv(1.0)
                if reply is None:
                    raise RuntimeError("the echo did not answer")
                if reply.arbitration_id == ECHO_REPLY_ID:
                    break
            echo.append(perf_ns() - t0)
        out["echo"] = _stats(echo)
        daq.setup()
        rig.mark()
        daq.start()
        sleep(daq_s)
        daq.stop()
        rig.mark()
        sleep(daq_s)  # idle: the broadcast's baseline window
        rig.mark()
        m.disconnect()
    stamps = np.asarray(daq.stamps, dtype=np.int64)
    steps = np.diff(stamps) // (TIMESTAMP_NS * 1000) if len(stamps) > 1 else np.zeros(0, int)
    out["daq"] = {"samples": len(stamps), "window_s": daq_s,
                  "samples_per_s": round(len(stamps) / daq_s, 1),
                  "missing_in_timestamps": int(np.sum(np.maximum(steps - 1, 0))),
                  "odts_lost_at_slave": rig.xcp.daq.stats.odts_lost,
                  "odts_sent": rig.xcp.daq.stats.odts_sent}
    return out


def _pyxcp_app(master_id: int, slave_id: int, channel: str) -> Any:
    import logging

    from pyxcp.config import create_application_from_config

    app = create_application_from_config({
        "Transport": {"CAN": {"interface": "virtual", "channel": channel,
                              "can_id_master": master_id, "can_id_slave": slave_id}},
        "General": {"disable_error_handling": True, "connect_retries": 0},
    }, log_level=logging.WARNING)
    app.transport.layer = "CAN"
    app.transport.timeout = 2.0
    return app


def _window(a: tuple[int, int, int], b: tuple[int, int, int]) -> dict[str, Any]:
    ticks, sent = b[1] - a[1], b[2] - a[2]
    return {"window_s": round((b[0] - a[0]) / NS_PER_S, 3), "ecu_ticks": ticks,
            "estimates_sent": sent, "ticks_kept_pct": round(100.0 * sent / max(ticks, 1), 2)}


def bench_daq_cost(ticks: int = 2000, blocks: int = 4) -> dict[str, Any]:
    """On the simulated clock (no pacing, so the host's load weighs on both sides alike): the
    CPU time of the ECU's 1 ms tick with the DAQ list of the live part running against the same
    ticks without it, in alternating blocks of `ticks`, same run. The list is set up through
    the slave's command processor (the packets a master sends; pyxcp needs a thread per bus)."""
    import struct

    from vecu.assembly import (
        TICK_NS,
        build_functions,
        build_plant,
        schedule_plant,
    )
    from vecu.bus import open_bus
    from vecu.clock import SimClock
    from vecu.codec import DbcCodec
    from vecu.config import RunConfig
    from vecu.ecu.node import EcuNode
    from vecu.runner import attach_xcp_server
    from vecu.scheduler import Scheduler

    config = RunConfig(duration_s=2 * blocks * ticks / 1000 + 1.0, kill_tps_at_s=None)
    codec = DbcCodec()
    channel = f"vecu-bench-xcp-cost-{next(_channels)}-{perf_ns()}"
    buses = [open_bus("virtual", channel) for _ in range(2)]
    try:
        fns = build_functions(config, codec)
        ecu = EcuNode(buses[1], codec, fns.enabled())
        xcp = attach_xcp_server(ecu, config)
        assert xcp is not None
        sched = Scheduler(SimClock())
        schedule_plant(sched, build_plant(config, codec, buses[0]))
        times: list[int] = []
        tick = ecu.tick

        def timed(t_ns: int) -> None:
            t0 = perf_ns()
            tick(t_ns)
            times.append(perf_ns() - t0)

        sched.every(TICK_NS, timed, name="ecu", priority=10)
        addr = {m.name: m.address for m in xcp.measurements}
        handle = xcp.proc.handle
        def entry(name: str, size: int) -> bytes:
            return bytes([0xE1, 0xFF, size, 0]) + struct.pack("<I", addr[name])

        # as pyxcp lays the live part's list out on CAN: ODT 0 the timestamp only, ODT 1 the
        # estimate and the TPS status, ODT 2 the sigma
        setup = [b"\xff\x00", b"\xd6", b"\xd5\x00\x01\x00", b"\xd4\x00\x00\x00\x03",
                 b"\xd3\x00\x00\x00\x00\x00", b"\xd3\x00\x00\x00\x01\x02",
                 b"\xd3\x00\x00\x00\x02\x01", b"\xe2\x00\x00\x00\x01\x00",
                 entry("throttle.estimate_deg", 4), entry("monitor.tps.status", 1),
                 b"\xe2\x00\x00\x00\x02\x00", entry("throttle.sigma_deg", 4)]
        setup.append(b"\xe0\x10\x00\x00\x00\x00\x01\x00")  # timestamps, event 0 (1 ms)
        for cto in setup:
            if handle(cto, 0)[0][0] != 0xFF:
                raise RuntimeError(f"DAQ set-up refused: {cto.hex(' ')}")
        t = 0
        sched.run_until(t)
        with_daq: list[int] = []
        without: list[int] = []
        for block in range(2 * blocks):
            daq_on = block % 2 == 1
            handle(b"\xde\x01\x00\x00" if daq_on else b"\xde\x00\x00\x00", t)
            times.clear()
            t += ticks * TICK_NS
            sched.run_until(t)
            (with_daq if daq_on else without).extend(times)
        sent = xcp.daq.stats.odts_sent
    finally:
        for bus in buses:
            bus.shutdown()
    a, b = np.asarray(without, float) / 1e3, np.asarray(with_daq, float) / 1e3
    return {"ticks_each": len(a), "tick_us_p50": round(float(np.median(a)), 1),
            "tick_us_p50_daq": round(float(np.median(b)), 1),
            "tick_us_mean": round(float(a.mean()), 1), "tick_us_mean_daq": round(float(b.mean()), 1),
            "ratio_p50": round(float(np.median(b) / np.median(a)), 3), "odts_sent": sent}


def bench_xcp(commands: int = 200, daq_s: float = 2.0) -> dict[str, Any]:
    """The XCP figures of the docstring, live in this process."""
    try:
        import pyxcp.master  # noqa: F401 - imported before the clock starts
    except ImportError:
        raise UnavailableError("vecu bench --only xcp needs pyxcp (pip install pyxcp)") from None
    from vecu.live.process import tighten_timer_slack
    from vecu.runner import warm_up

    tighten_timer_slack()
    max_s = 60.0 + 3 * daq_s + commands * 0.02
    rig = _Rig(max_s)
    out: dict[str, Any] = {}

    def body() -> None:
        try:
            out.update(_master_work(rig, commands, daq_s))
        except BaseException as exc:  # noqa: BLE001 - re-raised on the bench's thread
            out["error"] = exc

    previous = sys.getswitchinterval()
    try:
        warm_up(rig.config)
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        thread = threading.Thread(target=body, name="xcp-master", daemon=True)

        def check(t_ns: int) -> None:
            if not thread.is_alive():
                rig.sched.stop()

        rig.sched.every(10 * NS_PER_MS, check, name="master-done", priority=99)
        thread.start()
        rig.clock.start()
        rig.sched.run_until(round(max_s * NS_PER_S))
        thread.join(30.0)
    finally:
        sys.setswitchinterval(previous)
        gc.unfreeze()
        rig.close()
    if "error" in out:
        raise out["error"]
    m = rig.marks
    out["broadcast_daq"] = _window(m[0], m[1])
    out["broadcast_idle"] = _window(m[1], m[2])
    out["latency_ratio"] = round(out["command"]["p50_ms"] / max(out["echo"]["p50_ms"], 1e-9), 2)
    out["daq_cost"] = bench_daq_cost(ticks=max(200, round(daq_s * 400)))
    return out


def format_xcp(r: dict[str, Any]) -> str:
    c, e, d, k = r["command"], r["echo"], r["daq"], r["daq_cost"]
    bd, bi = r["broadcast_daq"], r["broadcast_idle"]
    return "\n".join([
        "xcp (live, WallClock, pyxcp master; same run):",
        (f"  DAQ 1 ms event: {d['samples_per_s']} samples/s over {d['window_s']} s "
         f"({d['samples']} samples, {d['missing_in_timestamps']} missing in the timestamps), "
         f"ODTs lost {d['odts_lost_at_slave']} of {d['odts_sent'] + d['odts_lost_at_slave']}"),
        (f"  broadcast ticks kept: {bd['ticks_kept_pct']} % with DAQ ({bd['estimates_sent']} of "
         f"{bd['ecu_ticks']}), {bi['ticks_kept_pct']} % idle ({bi['estimates_sent']} of "
         f"{bi['ecu_ticks']})"),
        (f"  command latency SHORT_UPLOAD p50 {c['p50_ms']} p99 {c['p99_ms']} ms vs bare echo "
         f"p50 {e['p50_ms']} p99 {e['p99_ms']} ms on the same tick: x{r['latency_ratio']}"),
        (f"  ECU tick CPU (simulated clock, alternating blocks): p50 {k['tick_us_p50_daq']} us "
         f"with the 1 ms DAQ list vs {k['tick_us_p50']} us without: x{k['ratio_p50']} "
         f"({k['ticks_each']} ticks each)"),
    ])
