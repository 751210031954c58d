"""`vecu bench --only restbus`: restbus timing against python-can's own `send_periodic`, in the
same run, on the same kind of bus (python-can's virtual interface, one process).

The load is a generated database of 40 messages (ten each at 10, 20, 50 and 100 ms: 1800
frames/s offered). vecu's restbus runs it live (one scheduler thread, absolute deadlines) with
every send time kept; then python-can sends the same 40 frames with `bus.send_periodic` (one
thread per task, python-can's own timing) for as long, and the send times come from the virtual
bus's stamps (the wall time as each frame is sent; vecu's: its clock as each frame is sent).
Per message and frame: period error = the gap to the previous frame minus the cycle time,
p50 / p99 / max of |error| over every message; frames per second sustained against offered. On the simulated clock: wall time per simulated second and that every period is exact.
"""

from __future__ import annotations

import itertools
import tempfile
from pathlib import Path
from typing import Any

import can
import numpy as np

from vecu.bus import open_bus
from vecu.clock import SimClock, Stopwatch, sleep
from vecu.restbus.node import RestbusNode
from vecu.restbus.session import RestbusRun, run_restbus
from vecu.restbus.spec import RestbusConfig, build_plans
from vecu.scheduler import Scheduler

CYCLES_MS = (10, 20, 50, 100)
STAGGER_MS = 0.25  # the staggered run: message k first at k x 0.25 ms
PER_CYCLE = 10
_channels = itertools.count()


def bench_dbc() -> str:
    """The load: PER_CYCLE messages at each of CYCLES_MS, 8 bytes, two signals each."""
    lines = ['VERSION ""', "NS_ :", "BS_:", "BU_: BENCH", ""]
    attrs = ['BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;', 'BA_DEF_DEF_ "GenMsgCycleTime" 0;']
    k = 0
    for cycle in CYCLES_MS:
        for _ in range(PER_CYCLE):
            can_id = 0x100 + k
            lines += [f"BO_ {can_id} Bench_{k}: 8 BENCH",
                      f' SG_ B{k}_A : 0|16@1+ (0.01,0) [0|600] "" Vector__XXX',
                      f' SG_ B{k}_B : 16|32@1+ (1,0) [0|100000] "" Vector__XXX', ""]
            attrs.append(f'BA_ "GenMsgCycleTime" BO_ {can_id} {cycle};')
            k += 1
    return "\n".join(lines + attrs) + "\n"


def _errors(times_ns: dict[int, list[int]], period_ns: dict[int, int]) -> dict[str, float]:
    errs = np.concatenate([np.abs(np.diff(np.asarray(t, dtype=np.int64)) - period_ns[i])
                           for i, t in times_ns.items() if len(t) > 1]) / 1e3
    return {"p50_us": round(float(np.percentile(errs, 50)), 1),
            "p99_us": round(float(np.percentile(errs, 99)), 1),
            "max_us": round(float(errs.max()), 1), "gaps": int(errs.size)}


def _vecu_live(db: str, seconds: float, stagger_ms: float = 0.0) -> dict[str, Any]:
    res = run_restbus(RestbusRun(RestbusConfig((db,), stagger_ms=stagger_ms),
                                 duration_s=seconds, realtime=True,
                                 interface="virtual", channel=f"rb-bench-{next(_channels)}",
                                 keep_times=True))
    node = res.node
    times = {p.codec.frame_id: s.times_ns or [] for p, s in zip(node.plans, node.states)}
    periods = {p.codec.frame_id: p.period_ns for p in node.plans}
    return {**_errors(times, periods), "frames": node.frames_sent,
            "fps": round(node.frames_sent / res.summary["wall_s"]),
            "overruns": res.summary["overruns"]}


def _python_can_periodic(db: str, seconds: float) -> dict[str, Any]:
    plans, _, _ = build_plans(RestbusConfig((db,)))
    channel = f"rb-bench-pc-{next(_channels)}"
    # python-can's virtual interface, each frame stamped with the wall time as it is sent
    tx = open_bus(interface="virtual", channel=channel, preserve_timestamps=False)
    rx = open_bus(interface="virtual", channel=channel, preserve_timestamps=False)
    times: dict[int, list[int]] = {p.codec.frame_id: [] for p in plans}
    try:
        tasks = []
        watch = Stopwatch()
        for p in plans:
            values = {n: src(0.0) for n, src in p.sources.items()}
            msg = can.Message(arbitration_id=p.codec.frame_id, is_extended_id=False,
                              data=p.codec.encode(values))
            tasks.append(tx.send_periodic(msg, p.period_ns / 1e9))
        while watch.elapsed() < seconds:
            sleep(0.05)
            while (m := rx.recv(0.0)) is not None:  # stamped by the virtual bus at send
                times[m.arbitration_id].append(round(m.timestamp * 1e9))
        for t in tasks:
            t.stop()
        wall = watch.elapsed()
        while (m := rx.recv(0.0)) is not None:
            times[m.arbitration_id].append(round(m.timestamp * 1e9))
    finally:
        tx.shutdown()
        rx.shutdown()
    frames = sum(len(t) for t in times.values())
    periods = {p.codec.frame_id: p.period_ns for p in plans}
    return {**_errors(times, periods), "frames": frames, "fps": round(frames / wall)}


def _simulated(db: str, seconds: float) -> dict[str, Any]:
    plans, _, _ = build_plans(RestbusConfig((db,)))
    sent = [0]

    def send(msg: can.Message) -> bool:
        sent[0] += 1
        return True
    node = RestbusNode(plans, send, np.random.default_rng(0), keep_times=True)
    sched = Scheduler(SimClock())
    node.schedule(sched)
    watch = Stopwatch()
    sched.run_until(round(seconds * 1e9))
    wall = watch.elapsed()
    exact = all(set(np.diff(s.times_ns or [])) == {p.period_ns}
                for p, s in zip(plans, node.states))
    return {"frames": sent[0], "x_realtime": round(seconds / wall, 1),
            "fps": round(sent[0] / wall), "exact_periods": exact}


def bench_restbus(seconds: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        db = str(Path(tmp) / "bench.dbc")
        Path(db).write_text(bench_dbc())
        offered = sum(PER_CYCLE * 1000 // c for c in CYCLES_MS)
        vecu = _vecu_live(db, seconds)
        staggered = _vecu_live(db, seconds, STAGGER_MS)
        baseline = _python_can_periodic(db, seconds)
        sim = _simulated(db, max(seconds, 5.0))
    return {"seconds": seconds, "messages": PER_CYCLE * len(CYCLES_MS),
            "offered_fps": offered, "vecu": vecu, "vecu_staggered": staggered,
            "python_can": baseline, "simulated": sim,
            "p99_ratio": round(baseline["p99_us"] / vecu["p99_us"], 2) if vecu["p99_us"] else None,
            "p99_ratio_staggered": (round(baseline["p99_us"] / staggered["p99_us"], 2)
                                    if staggered["p99_us"] else None)}


def format_restbus(r: dict[str, Any]) -> str:
    v, g, b, s = r["vecu"], r["vecu_staggered"], r["python_can"], r["simulated"]
    return "\n".join([
        (f"Restbus, {r['messages']} messages at 10/20/50/100 ms ({r['offered_fps']} frames/s "
         f"offered), live {r['seconds']:g} s on python-can's virtual bus:"),
        (f"  vecu restbus (all at once) period error p50 {v['p50_us']} / p99 {v['p99_us']} / "
         f"max {v['max_us']} us, {v['fps']} frames/s sustained, {v['overruns']} overruns"),
        (f"  vecu restbus --stagger {STAGGER_MS:g} period error p50 {g['p50_us']} / p99 "
         f"{g['p99_us']} / max {g['max_us']} us, {g['fps']} frames/s sustained"),
        (f"  python-can send_periodic period error p50 {b['p50_us']} / p99 {b['p99_us']} / max "
         f"{b['max_us']} us, {b['fps']} frames/s sustained"),
        (f"  p99 ratio python-can / vecu: {r['p99_ratio']}x (staggered: "
         f"{r['p99_ratio_staggered']}x)"),
        (f"  simulated clock: {s['x_realtime']}x real time, {s['fps']} frames/s generated, "
         f"periods exact: {s['exact_periods']}")])
