"""`vecu bench --only gateway`, the routing half: frames per second through the routing engine
(a frame route with a new ID and a signal route repacking two signals, as docs/gateway.md's
quick start, between two buses) against a bare python-can receive on its own virtual bus, in
the same run; then per-route latency with the live gateway's step (vecu.gateway.live_routing)
polling the buses every 1 ms while frames arrive at a seeded random phase. The kernel's can-gw
beside vecu needs AF_CAN (tests/socketcan/test_routing_vcan.py on a real kernel); elsewhere it
is skipped with the reason."""

from __future__ import annotations

import json
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import can

from vecu.bus import open_baseline_virtual_bus, open_bus
from vecu.clock import NS_PER_S, perf_ns, sleep, wall_time
from vecu.codec import DbcCodec
from vecu.gateway.live_routing import LiveRouting
from vecu.gateway.routes_config import parse_routing_config
from vecu.live.scenario import stop_process
from vecu.rng import rng_streams

ROUTES: dict[str, Any] = {
    "routes": [
        {"from": "src", "to": "dst", "messages": ["ECU_SpeedEstimate"], "id": 0x420},
        {"from": "src", "to": "dst", "target": "ECU_Status", "send": "on_change",
         "signals": {"ECU_Overruns": "ECU_ThrottleEstimate.THR_AliveCounter"}},
    ]}


def _frames(n: int) -> list[can.Message]:
    codec = DbcCodec()
    spd, thr = codec["ECU_SpeedEstimate"], codec["ECU_ThrottleEstimate"]
    return [(spd if i % 2 else thr).frame(
        {**(spd if i % 2 else thr).start_values, "SPD_VehSpeed": float(i % 200),
         "THR_AliveCounter": float(i % 15)}, 0.0) for i in range(n)]


def _config(tag: str) -> Any:
    buses = {name: {"interface": "virtual", "channel": f"bench-route-{tag}-{name}",
                    "dbc": ["vecu"]} for name in ("src", "dst")}
    return parse_routing_config({"buses": buses, **ROUTES}, "<bench>")


def _baseline(frames: list[can.Message]) -> float:
    """python-can's own virtual bus: frames/s taken by recv() (sent beforehand)."""
    tx, rx = open_baseline_virtual_bus("bench-route-base"), open_baseline_virtual_bus(
        "bench-route-base")
    try:
        for m in frames:
            tx.send(m)
        t0, n = perf_ns(), 0
        while rx.recv(0.0) is not None:
            n += 1
        return n * NS_PER_S / max(perf_ns() - t0, 1)
    finally:
        tx.shutdown()
        rx.shutdown()


def _through(frames: list[can.Message]) -> tuple[float, dict[str, Any]]:
    """frames/s taken from the source bus, routed and sent on the target bus by one step of
    the live gateway (the frames sent beforehand, as for the baseline)."""
    live = LiveRouting(_config("rate"))
    tx = open_bus("virtual", "bench-route-rate-src")
    sink = open_bus("virtual", "bench-route-rate-dst")
    try:
        for m in frames:
            tx.send(m)
        t0 = perf_ns()
        live.step(0)
        return len(frames) * NS_PER_S / max(perf_ns() - t0, 1), live.summary()
    finally:
        live.close()
        tx.shutdown()
        sink.shutdown()


def _latency(frames: list[can.Message], seed: int) -> dict[str, Any]:
    """Each frame sent (stamped with the wall time), then the 1 ms step after a random share
    of the step: the latency a frame sees in the live gateway's loop."""
    rng = rng_streams(seed, ("bench.routing",))["bench.routing"]
    live = LiveRouting(_config("lat"))
    tx = open_bus("virtual", "bench-route-lat-src")
    sink = open_bus("virtual", "bench-route-lat-dst")
    try:
        t0 = perf_ns()
        for m in frames:
            m.timestamp = wall_time()
            tx.send(m)
            sleep(float(rng.uniform(0.0, 0.001)))
            live.step(perf_ns() - t0)
        return live.summary()
    finally:
        live.close()
        tx.shutdown()
        sink.shutdown()


CANGW_RULE = ["-s", "vcan0", "-d", "vcan1", "-e", "-f", "123:7FF", "-m",
              "SET:I:321.0.0000000000000000"]  # 0x123 on vcan0 -> 0x321 on vcan1 (-e: echo on vcan)
KERNEL_CONFIG = """
[buses.src]
interface = "socketcan"
channel = "vcan0"
dbc = ["vecu"]

[buses.dst]
interface = "socketcan"
channel = "vcan1"
dbc = ["vecu"]

[[routes]]
from = "src"
to = "dst"
ids = [0x123]
id = 0x421
"""
START_S = 300.0  # an emulated guest starts a vecu process in 10-60 s


def kernel_unavailable() -> str | None:
    """None where vcan0 and vcan1 open on AF_CAN and can-utils' cangw, candump and cangen
    are here; else why not."""
    try:
        for channel in ("vcan0", "vcan1"):
            with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
                s.bind((channel,))
    except (OSError, AttributeError) as exc:
        return f"no SocketCAN vcan0/vcan1 here ({exc}): run through ../shared/vcan-vm/vcan-run"
    missing = [t for t in ("cangw", "candump", "cangen") if shutil.which(t) is None]
    return f"can-utils missing: {', '.join(missing)}" if missing else None


def _wait(cond: Any, timeout_s: float) -> None:
    end = perf_ns() + round(timeout_s * NS_PER_S)
    while not cond() and perf_ns() < end:
        sleep(0.1)


def kernel_comparison(out: Path, frames: int = 40) -> dict[str, Any]:
    """On a real kernel: cangen sends `frames` frames 0x123 on vcan0 (payload counting up),
    `vecu gateway` routes them to vcan1 as 0x421 and the kernel's can-gw as 0x321; one candump
    on both interfaces timestamps all three. The frames each way (candump time, payload), the
    latency medians from those timestamps and vecu's own route figures."""
    (out / "gw.toml").write_text(KERNEL_CONFIG)
    dump_path = out / "candump.log"
    procs: list[subprocess.Popen] = []
    subprocess.run(["cangw", "-A", *CANGW_RULE], check=True, capture_output=True, timeout=60)
    try:
        with open(dump_path, "w") as dump, open(out / "gw.err", "w") as err:
            procs.append(subprocess.Popen(["candump", "-L", "vcan0", "vcan1"], stdout=dump))
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "vecu", "gateway", "--config", str(out / "gw.toml"),
                 "--doip-port", "0", "--no-status", "--quiet", "--ready-file",
                 str(out / "gw.ready"), "--summary", str(out / "gw.json")], stderr=err))
        gw = procs[1]
        _wait(lambda: (out / "gw.ready").exists() or gw.poll() is not None, START_S)
        if gw.poll() is not None:
            raise RuntimeError(f"vecu gateway ended: {(out / 'gw.err').read_text()[-2000:]}")
        subprocess.run(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "20", "-n",
                        str(frames)], check=True, timeout=START_S)
        _wait(lambda: dump_path.read_text().count(" vcan1 421#") >= frames, 120.0)
        gw_exit = stop_process(gw, signal.SIGTERM)
        stop_process(procs[0], signal.SIGINT)
    finally:
        for proc in procs:
            if proc.poll() is None:
                stop_process(proc, signal.SIGKILL, 10.0)
        subprocess.run(["cangw", "-D", *CANGW_RULE], check=False, capture_output=True,
                       timeout=60)
    rows = []
    for line in dump_path.read_text().splitlines():
        stamp, iface, frame = line.split()[:3]
        can_id, _, data = frame.partition("#")
        rows.append((float(stamp.strip("()")), iface, int(can_id, 16), data.lower()))
    sent = [(t, d) for t, iface, i, d in rows if iface == "vcan0" and i == 0x123]
    res: dict[str, Any] = {"sent": sent, "gateway_exit": gw_exit,
                           "routing": json.loads((out / "gw.json").read_text())["routing"]}
    for name, out_id in (("vecu", 0x421), ("can_gw", 0x321)):
        got = [(t, d) for t, iface, i, d in rows if iface == "vcan1" and i == out_id]
        res[name] = got
        lat = [(tg - ts) * 1e6 for (ts, _), (tg, _) in zip(sent, got)]
        res[f"{name}_median_us"] = round(statistics.median(lat), 1) if lat else None
    v, k = res["vecu_median_us"], res["can_gw_median_us"]
    res["ratio"] = round(v / k, 1) if v is not None and k else None
    return res


def _can_gw() -> dict[str, Any]:
    why = kernel_unavailable()
    if why is not None:
        return {"skipped": why}
    with tempfile.TemporaryDirectory() as tmp:
        r = kernel_comparison(Path(tmp))
    return {k: r[k] for k in ("vecu_median_us", "can_gw_median_us", "ratio")} | {
        "frames": len(r["sent"]), "routed_vecu": len(r["vecu"]), "routed_can_gw": len(r["can_gw"])}


def bench_routing(frames: int, latency_frames: int, seed: int = 0) -> dict[str, Any]:
    msgs = _frames(frames)
    base = _baseline(msgs)
    rate, through = _through(_frames(frames))
    lat = _latency(_frames(latency_frames), seed)
    return {"frames": frames, "baseline_per_s": round(base), "routed_per_s": round(rate),
            "ratio": round(rate / base, 3) if base else None,
            "routes": through["routes"], "latency": lat["routes"], "can_gw": _can_gw()}


def format_routing(r: dict[str, Any]) -> str:
    lines = [f"Routing between buses (in-process virtual buses, {r['frames']} frames):",
             (f"  taken, routed and sent by the gateway's step  {r['routed_per_s']} frames/s; "
              f"python-can recv alone {r['baseline_per_s']} frames/s: {r['ratio']}x")]
    for name, s in r["latency"].items():
        lat = s["latency_us"]
        lines.append(f"  {name} latency (1 ms step, random arrival phase): min/mean/p99/max "
                     f"{lat['min']}/{lat['mean']}/{lat['p99']}/{lat['max']} us over "
                     f"{lat['count']} frames")
    k = r["can_gw"]
    lines.append(f"  can-gw beside vecu: skipped: {k['skipped']}" if "skipped" in k else
                 f"  vcan0 -> vcan1 on this kernel, from one candump: vecu median "
                 f"{k['vecu_median_us']} us, can-gw {k['can_gw_median_us']} us: {k['ratio']}x "
                 f"({k['routed_vecu']}/{k['routed_can_gw']} of {k['frames']} frames routed)")
    return "\n".join(lines)
