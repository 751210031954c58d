"""UDS request -> response latency (issue 17 item 5), against baselines from the same run.

A udsoncan Client over can-isotp (a real tester, on its own thread) asks the running ECU (plant +
ECU + UDS server on one virtual channel) for a single-frame ReadDataByIdentifier (0x0100,
throttle angle: 5-byte answer) and the multi-frame VIN (0xF190: 20-byte answer, first frame,
flow control, consecutive frames), twice:

- on the simulated clock: the test thread steps the clock 1 ms at a time while the tester talks;
  latency in simulated ms (the ECU answers in ticks, so this is its timing as a tester sees it);
- live: the same nodes paced by a WallClock in this process (virtual bus), latency in wall ms.

Baselines measured in the same run: a bare ISO-TP echo served by a 1 ms task on the same clock
and scheduler (3-byte request, answers of the same 5 and 20 bytes: transport and tick
quantisation without UDS; on a virtual channel of its own, the same in-process queues), and the
ECU's broadcast period. Meanwhile every estimate broadcast is
counted: ECU_ThrottleEstimate frames seen on the bus against the ECU's 1 ms releases, and the
largest gap between consecutive ones.
"""

from __future__ import annotations

import gc
import itertools
import sys
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S, SimClock, WallClock, perf_ns, sleep
from vecu.uds.transport import Endpoint, to_can

SINGLE_DID, VIN_DID = 0x0100, 0xF190
ECHO_RX, ECHO_TX = 0x7E1, 0x7E9  # the echo's request / answer IDs (unused by vecu's DBC)
SIZES = {"echo_single": 5, "echo_multi": 20}  # answer bytes, as RDBI 0x0100 and the VIN
# simulated clock: after a tick that sent a tester a frame, wall time allowed for its thread to
# react (flow control, or the next request) before the next tick, and the polling step
SIM_REACT_S, SIM_POLL_S = 0.05, 0.0001
SWITCH_INTERVAL_S = 0.0002  # live: the interpreter passes between the clock's and tester's threads
_channels = itertools.count()


class _Echo:
    """A bare ISO-TP server on the same bus and tick: answers a request [n, ...] with n bytes."""

    def __init__(self, bus: Any) -> None:
        self.bus = bus
        self._now = 0
        self.ep = Endpoint(ECHO_RX, ECHO_TX, lambda: self._now)

    def tick(self, t_ns: int) -> None:
        self._now = t_ns
        ep = self.ep
        while (msg := self.bus.recv(0.0)) is not None:
            if msg.arbitration_id == ECHO_RX and not msg.is_error_frame:
                ep.put(msg)
        ep.process()
        for payload in ep.payloads():
            ep.send(bytes(range(payload[0])))
        ep.process()
        while ep.out:
            self.bus.send(to_can(ep.out.popleft(), t_ns / NS_PER_S))


class _Rig:
    """Plant, ECU with its UDS server and the echo on one fresh virtual channel."""

    def __init__(self, clock: SimClock | WallClock, duration_s: float) -> None:
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
        from vecu.scheduler import Scheduler
        from vecu.uds.server import attach_uds

        # the lateral plant simulates its whole run up front: no longer than the bench needs
        self.config = RunConfig(duration_s=duration_s, kill_tps_at_s=None)
        codec = DbcCodec()
        channel = f"vecu-bench-uds-{next(_channels)}-{perf_ns()}"
        # the echo on a channel of its own: the same in-process queues, but the ECU does not
        # count its frames as unknown IDs
        self.buses = ([open_bus("virtual", channel) for _ in range(4)]
                      + [open_bus("virtual", channel + "-echo") for _ in range(2)])
        plant_bus, ecu_bus, self.tester_bus, self.sniffer, echo_bus, self.echo_client_bus = \
            self.buses
        self.watch = ([open_bus("virtual", channel), open_bus("virtual", channel + "-echo")]
                      if isinstance(clock, SimClock) else [])
        self.buses += self.watch
        uds = self.config.params.ecu.uds
        self.answer_ids = {uds.response_id, ECHO_TX}
        self.request_ids = {uds.request_id, uds.functional_id, ECHO_RX}
        self.estimate_id = codec["ECU_ThrottleEstimate"].frame_id
        self.fns = build_functions(self.config, codec)
        self.ecu = EcuNode(ecu_bus, codec, self.fns.enabled())
        self.uds = attach_uds(self.ecu, self.config.params.ecu.uds, self.config.seed)
        self.sched = Scheduler(clock)
        schedule_plant(self.sched, build_plant(self.config, codec, plant_bus))
        self.ecu_task = schedule_ecu(self.sched, self.ecu)
        self.marks: list[tuple[int, int, int, int]] = []
        self._mark_wanted: list[threading.Event] = []
        self.sched.every(NS_PER_MS, self._take_mark, name="mark", priority=90)
        self.stamps: list[float] = []
        self.echo = _Echo(echo_bus)
        self.sched.every(NS_PER_MS, self.echo.tick, name="echo", priority=15)  # after the ECU

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()

    def _last_frame(self) -> str | None:
        """Of the frames on the watched channels since the last call, whether the last
        relevant one went to a tester ('answer') or came from one ('request')."""
        last = None
        for bus in self.watch:
            while (msg := bus.recv(0.0)) is not None:
                if msg.arbitration_id in self.answer_ids:
                    last = "answer"
                elif msg.arbitration_id in self.request_ids:
                    last = "request"
        return last

    def settle(self) -> None:
        """After a simulated tick that sent a tester a frame: wait (wall time, at most
        SIM_REACT_S) for the tester's reaction (flow control, or its next request) to reach
        the bus, so that the next tick sees it whatever the host's load."""
        if self._last_frame() != "answer":
            return
        for _ in range(round(SIM_REACT_S / SIM_POLL_S)):
            sleep(SIM_POLL_S)
            if self._last_frame() is not None:
                return

    def mark(self) -> None:
        """The tester starts or ends a window: asks the scheduler's thread to note the clock
        time and the ECU's counters between two ticks (_take_mark), and waits for it."""
        done = threading.Event()
        self._mark_wanted.append(done)
        if not done.wait(30.0):
            raise RuntimeError("the clock did not run")

    def _take_mark(self, t_ns: int) -> None:
        while self._mark_wanted:
            task = self.ecu_task
            self.marks.append((t_ns, task.runs + task.skipped, self.fns.throttle.estimates_sent,
                               task.overruns))
            self._mark_wanted.pop().set()

    def idle(self) -> None:
        """After the requests: as long again without any, then a last mark (the baseline
        window of the broadcast count)."""
        (t0, *_), (t1, *_) = self.marks[-2], self.marks[-1]
        while self.sched.clock.now_ns() < t1 + (t1 - t0):
            sleep(0.0005)
        self.mark()

    def broadcast(self, first: int) -> dict[str, Any]:
        """Between marks `first` and `first + 1`: estimate frames heard on the bus against the
        ECU's 1 ms releases, and the largest gap between consecutive ones (their ECU-clock
        timestamps)."""
        (t0, rel0, est0, over0), (t1, rel1, est1, over1) = self.marks[first:first + 2]
        lo, hi = t0 / NS_PER_S, t1 / NS_PER_S
        stamps = [ts for ts in self.stamps if lo < ts <= hi]
        gap_ms = float(np.max(np.diff(stamps))) * 1e3 if len(stamps) > 1 else None
        return {"window_s": round((t1 - t0) / NS_PER_S, 3), "ecu_ticks": rel1 - rel0,
                "estimates_sent": est1 - est0, "estimates_heard": len(stamps),
                "lost": (rel1 - rel0) - (est1 - est0), "overruns": over1 - over0,
                "max_gap_ms": None if gap_ms is None else round(gap_ms, 3),
                "period_ms": NS_PER_MS / 1e6}

    def result(self, clock: str, lat: dict[str, list[int]]) -> dict[str, Any]:
        while (msg := self.sniffer.recv(0.0)) is not None:
            if msg.arbitration_id == self.estimate_id:
                self.stamps.append(msg.timestamp)
        return {"clock": clock, "latency": {k: _stats(v) for k, v in lat.items()},
                "broadcast": self.broadcast(0), "broadcast_idle": self.broadcast(1),
                "uds_requests": self.uds.stats.requests if self.uds else 0,
                "uds_negative": self.uds.stats.negative if self.uds else 0}


def _tester(rig: _Rig, requests: int, now_ns: Callable[[], int]) -> dict[str, list[int]]:
    """The udsoncan tester (and the echo's bare ISO-TP client): `requests` of each kind,
    interleaved; latencies in ns of `now_ns`."""
    import isotp
    import udsoncan
    from udsoncan.client import Client
    from udsoncan.connections import PythonIsoTpConnection

    class Raw(udsoncan.DidCodec):
        def __init__(self, n: int) -> None:
            self.n = n

        def encode(self, value: bytes) -> bytes:
            return value

        def decode(self, data: bytes) -> bytes:
            return data

        def __len__(self) -> int:
            return self.n

    config = {**udsoncan.configs.default_client_config,
              "data_identifiers": {SINGLE_DID: Raw(2), VIN_DID: Raw(17)},
              "request_timeout": 5.0, "p2_timeout": 2.0, "p2_star_timeout": 5.0,
              "use_server_timing": False}
    params = {"tx_padding": 0xCC, "blocking_send": False}
    uds_stack = isotp.CanStack(rig.tester_bus, params=params, address=isotp.Address(
        isotp.AddressingMode.Normal_11bits, txid=rig.config.params.ecu.uds.request_id,
        rxid=rig.config.params.ecu.uds.response_id))
    echo_conn = PythonIsoTpConnection(isotp.CanStack(
        rig.echo_client_bus, params=params,
        address=isotp.Address(isotp.AddressingMode.Normal_11bits, txid=ECHO_RX, rxid=ECHO_TX)))
    lat: dict[str, list[int]] = {"rdbi_single": [], "vin_multi": [], "echo_single": [],
                                 "echo_multi": []}

    def echo(n: int) -> None:
        echo_conn.send(bytes([n, 0, 0]))
        got = echo_conn.wait_frame(timeout=5.0, exception=True)
        if got is None or len(got) != n:
            raise RuntimeError(f"echo answered {got!r} to a request for {n} bytes")

    calls: list[tuple[str, Callable[[], Any]]] = []
    with Client(PythonIsoTpConnection(uds_stack), config=config) as client:
        echo_conn.open()
        try:
            calls = [("echo_single", lambda: echo(SIZES["echo_single"])),
                     ("rdbi_single", lambda: client.read_data_by_identifier(SINGLE_DID)),
                     ("echo_multi", lambda: echo(SIZES["echo_multi"])),
                     ("vin_multi", lambda: client.read_data_by_identifier(VIN_DID))]
            for _, call in calls:  # once each, unmeasured: first-call set-up
                call()
            rig.mark()
            for _ in range(requests):
                for name, call in calls:
                    t0 = now_ns()
                    call()
                    lat[name].append(now_ns() - t0)
            rig.mark()
            rig.idle()
        finally:
            echo_conn.close()
    return lat


def _run_tester(rig: _Rig, requests: int, now_ns: Callable[[], int],
                drive: Callable[[threading.Thread], None]) -> dict[str, list[int]]:
    out: dict[str, Any] = {}

    def body() -> None:
        try:
            out["lat"] = _tester(rig, requests, now_ns)
        except BaseException as exc:  # noqa: BLE001 - re-raised on the bench's thread
            out["error"] = exc

    thread = threading.Thread(target=body, name="uds-tester", daemon=True)
    thread.start()
    drive(thread)
    thread.join(30.0)
    if thread.is_alive():
        raise RuntimeError("the UDS tester did not finish")
    if "error" in out:
        raise out["error"]
    return out["lat"]


def _stats(ns: list[int]) -> dict[str, float]:
    ms = np.asarray(ns, dtype=float) / NS_PER_MS
    return {"n": int(ms.size), "p50_ms": round(float(np.percentile(ms, 50)), 3),
            "p99_ms": round(float(np.percentile(ms, 99)), 3), "max_ms": round(float(ms.max()), 3)}


def _run_s(requests: int) -> float:
    """An upper bound on a bench run's length (requests take a few ms each, twice: with the
    window without requests)."""
    return 30.0 + 0.1 * requests


def bench_uds_sim(requests: int) -> dict[str, Any]:
    """On the simulated clock: stepped 1 ms at a time while the tester talks, waiting after each
    tick that answered it for its reaction (Rig.settle); latencies in simulated time, the same
    in every run unless the tester takes longer than SIM_REACT_S of wall time to react."""
    max_s = _run_s(requests)
    rig = _Rig(SimClock(), max_s)
    t = [0]

    def drive(thread: threading.Thread) -> None:
        end = round(max_s * NS_PER_S)
        while thread.is_alive() and t[0] < end:
            t[0] += NS_PER_MS
            rig.sched.run_until(t[0])
            rig.settle()

    try:
        return rig.result("simulated", _run_tester(rig, requests, lambda: t[0], drive))
    finally:
        rig.close()


def bench_uds_live(requests: int) -> dict[str, Any]:
    """Live: the same nodes paced by a WallClock in this process (virtual bus), its final spin
    and timer slack as the live processes'; the interpreter's switch interval shortened so the
    tester's threads and the clock's pass it quickly."""
    from vecu.live.options import DEFAULT_SPIN_US
    from vecu.live.process import tighten_timer_slack
    from vecu.runner import warm_up

    tighten_timer_slack()  # as the live processes
    clock = WallClock(spin_ns=DEFAULT_SPIN_US * 1000)
    max_s = _run_s(requests)
    rig = _Rig(clock, max_s)

    def drive(thread: threading.Thread) -> None:
        def check(t_ns: int) -> None:
            if not thread.is_alive():
                rig.sched.stop()

        rig.sched.every(10 * NS_PER_MS, check, name="tester-done", priority=99)
        clock.start()
        rig.sched.run_until(round(max_s * NS_PER_S))

    import isotp  # noqa: F401 - imported before the clock starts, not on the tester's thread
    import udsoncan.client  # noqa: F401 - as above

    previous = sys.getswitchinterval()
    try:
        warm_up(rig.config)
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        return rig.result("wall", _run_tester(rig, requests, perf_ns, drive))
    finally:
        sys.setswitchinterval(previous)
        gc.unfreeze()
        rig.close()


def bench_uds(requests: int) -> dict[str, Any]:
    return {"requests": requests, "sim": bench_uds_sim(requests), "live": bench_uds_live(requests)}


def _line(s: dict[str, float]) -> str:
    return f"p50 {s['p50_ms']:.2f} / p99 {s['p99_ms']:.2f} / max {s['max_ms']:.2f} ms"


def _broadcast(b: dict[str, Any]) -> str:
    return (f"{b['estimates_heard']} frames heard over {b['ecu_ticks']} ECU ticks, {b['lost']} "
            f"ticks lost, largest gap {b['max_gap_ms']} ms, {b['overruns']} overruns")


def format_uds(r: dict[str, Any]) -> str:
    lines = [(f"UDS request -> response, udsoncan client over can-isotp, {r['requests']} requests "
             f"each (plant + ECU + UDS server on one virtual channel):")]
    for key, title in (("sim", "simulated clock (simulated ms)"),
                       ("live", "live, wall clock, virtual bus in one process (wall ms)")):
        m = r[key]
        lat, b, idle = m["latency"], m["broadcast"], m["broadcast_idle"]
        lines += [
            f"  {title}:",
            f"    RDBI 0x0100 (single frame)      {_line(lat['rdbi_single'])}",
            f"    RDBI 0xF190 VIN (multi-frame)   {_line(lat['vin_multi'])}",
            (f"    baseline: bare ISO-TP echo on the same clock and 1 ms tick: 5 B "
            f"{_line(lat['echo_single'])}; 20 B {_line(lat['echo_multi'])}"),
            (f"    estimate broadcast (period {b['period_ms']:g} ms) during the requests "
            f"({b['window_s']:g} s): {_broadcast(b)}"),
            f"    baseline: as long again without requests: {_broadcast(idle)}"]
    return "\n".join(lines)
