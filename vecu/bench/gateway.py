"""`vecu bench --only gateway`: a UDS request through the DoIP gateway against the same request
sent directly on CAN, in the same run (issue 40 item 7).

In a private network namespace (udp_multicast and TCP on loopback): two `vecu ecu` processes
(0x7E0/0x7E8 and 0x7E1/0x7E9) and `vecu gateway`. One tester process alternates a
ReadDataByIdentifier 0x0100 (single frame both ways) sent
- directly on CAN through can-isotp (udsoncan's PythonIsoTpConnection, the baseline) to the
  second ECU, and
- through the gateway with doipclient (TCP -> gateway -> ISO-TP -> ECU and back) to the first,
so both see the same kind of ECU process, load and moment (two testers on one ECU's diagnostic
IDs would hear each other's answers); latency is request sent -> response received.
Then requests per second through the gateway: one tester back to back, and four concurrent
testers (their own TCP sockets and source addresses) spread over the two ECUs; the router takes
one request per ECU at a time and answers a second with NACK 0x06 (target busy), counted.

`python -m vecu.bench.gateway OUTDIR REQUESTS SECONDS` is the part run inside the namespace.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from vecu.clock import NS_PER_S, perf_ns, sleep
from vecu.live.netns import namespace_prefix, python_module, run_in_namespace

GROUP = "239.74.163.2"
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
REQUEST = b"\x22\x01\x00"  # RDBI 0x0100: 3-byte request, 5-byte answer: single frames
ECUS = {0x0010: (0x7E0, 0x7E8), 0x0011: (0x7E1, 0x7E9)}
TESTERS = 4


def _pct(ms: list[float]) -> dict[str, Any]:
    if not ms:
        return {"count": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}
    a = np.asarray(ms)
    return {"count": len(ms), "p50_ms": round(float(np.percentile(a, 50)), 3),
            "p99_ms": round(float(np.percentile(a, 99)), 3), "max_ms": round(float(a.max()), 3)}


def _wait(path: Path, timeout_s: float = 120.0) -> None:
    t0 = perf_ns()
    while not path.exists():
        if perf_ns() - t0 > timeout_s * NS_PER_S:
            raise TimeoutError(f"{path.name} not written in {timeout_s:g} s")
        sleep(0.02)


def _start(out: Path, name: str, argv: list[str]) -> subprocess.Popen:
    from vecu.live.children import spawn

    with open(out / f"{name}.err", "w") as err:
        proc = spawn([sys.executable, "-m", "vecu", *argv, "--ready-file",
                      str(out / f"{name}.ready"), "--summary", str(out / f"{name}.json"),
                      "--quiet", "--no-status"], new_group=False, stderr=err)
    _wait(out / f"{name}.ready")
    return proc


def _direct_client(bus: Any) -> Any:
    from vecu.uds.transport import tester_connection

    req, resp = ECUS[0x0011]
    return tester_connection(bus, req, resp)


def _timed(fn: Any) -> float:
    t0 = perf_ns()
    fn()
    return (perf_ns() - t0) / 1e6


def _doip_request(c: Any, target: int) -> bytes:
    c.send_diagnostic_to_address(target, bytearray(REQUEST))
    while True:
        msg = c.read_doip(timeout=2.0)
        if type(msg).__name__ == "DiagnosticMessage" and msg.source_address == target:
            return bytes(msg.user_data)


def _rate(clients: list[Any], seconds: float) -> dict[str, Any]:
    """Back-to-back requests from each client (its own thread) for `seconds`: answers per
    second, and the requests the router refused as busy (NACK 0x06)."""
    done = [0] * len(clients)
    busy = [0] * len(clients)
    end = perf_ns() + round(seconds * NS_PER_S)

    def run(k: int) -> None:
        target = list(ECUS)[k % len(ECUS)]
        while perf_ns() < end:
            try:
                _doip_request(clients[k], target)
                done[k] += 1
            except OSError as exc:  # doipclient: a diagnostic NACK (busy: another's request)
                if "code: 6" not in str(exc):
                    raise
                busy[k] += 1

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(clients))]
    t0 = perf_ns()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = (perf_ns() - t0) / NS_PER_S
    return {"testers": len(clients), "answers": sum(done), "seconds": round(elapsed, 3),
            "per_s": round(sum(done) / elapsed, 1), "busy_nacks": sum(busy)}


def measure(out: Path, requests: int, seconds: float) -> dict[str, Any]:
    """Inside the namespace: start the nodes, measure, stop them."""
    from doipclient import DoIPClient

    from vecu.bus import open_bus
    from vecu.live.scenario import stop_all

    subprocess.run(["ip", "link", "set", "lo", "up"], check=False)
    procs: list[subprocess.Popen] = []
    res: dict[str, Any] = {}
    try:
        ecu = ["ecu", *BUS, "--sync-timeout", "0", "--tps-timeout-cycles", "10000"]
        procs.append(_start(out, "ecu_a", ecu))
        procs.append(_start(out, "ecu_b", [*ecu, "--instance", "1"]))
        procs.append(_start(out, "gateway", ["gateway", *BUS]))
        bus = open_bus("udp_multicast", GROUP)
        direct = _direct_client(bus)
        doip = DoIPClient("127.0.0.1", 0x0010)
        try:
            for _ in range(5):  # warm-up: both paths
                direct.send(REQUEST)
                direct.wait_frame(timeout=2.0)
                _doip_request(doip, 0x0010)
            d_ms, g_ms = [], []
            for _ in range(requests):  # alternated: the same moments for both
                d_ms.append(_timed(lambda: (direct.send(REQUEST), direct.wait_frame(timeout=2.0))))
                g_ms.append(_timed(lambda: _doip_request(doip, 0x0010)))
            res["direct"], res["gateway"] = _pct(d_ms), _pct(g_ms)
            res["rate_1"] = _rate([doip], seconds)
            more = [DoIPClient("127.0.0.1", 0x0010, client_logical_address=0x0E01 + k)
                    for k in range(TESTERS - 1)]
            res[f"rate_{TESTERS}"] = _rate([doip, *more], seconds)
            for c in more:
                c.close()
        finally:
            doip.close()
            direct.close()
            bus.shutdown()
    finally:
        stop_all(procs)
    gw = json.loads((out / "gateway.json").read_text())
    res["gateway_summary"] = {"bad_input_total": gw["doip"]["bad_input_total"],
                              "handler_errors": gw["doip"]["handler_errors"],
                              "cpu_pct": gw["cpu_pct"],
                              "exec_us": gw["ticks"]["gateway"]["exec_us"]}
    return res


def bench_gateway(requests: int = 200, seconds: float = 3.0) -> dict[str, Any]:
    prefix, reason = namespace_prefix()
    if prefix is None:
        return {"skipped": reason}
    with tempfile.TemporaryDirectory(prefix="vecu-bench-gateway-") as tmp:
        res = run_in_namespace(python_module("vecu.bench.gateway", tmp, str(requests),
                                             str(seconds)), timeout=120 + 0.2 * requests)
        if res.returncode != 0:
            return {"skipped": f"the run failed (exit {res.returncode}): "
                               f"{res.stderr.strip().splitlines()[-1:] or ''}"}
        out: dict[str, Any] = json.loads(res.stdout.strip().splitlines()[-1])
    d, g = out["direct"]["p50_ms"], out["gateway"]["p50_ms"]
    out["ratio_p50"] = round(g / d, 2) if d else None
    d99, g99 = out["direct"]["p99_ms"], out["gateway"]["p99_ms"]
    out["ratio_p99"] = round(g99 / d99, 2) if d99 else None
    return out


def format_gateway(r: dict[str, Any]) -> str:
    if "skipped" in r:
        return f"Gateway (DoIP -> CAN): skipped: {r['skipped']}"
    d, g = r["direct"], r["gateway"]
    r1, r4 = r["rate_1"], r[f"rate_{TESTERS}"]
    return "\n".join([
        "Gateway (DoIP -> ISO-TP -> two live ECUs on udp_multicast, one run):",
        (f"  RDBI 0x0100 through the gateway (doipclient)  p50 {g['p50_ms']} / p99 "
         f"{g['p99_ms']} / max {g['max_ms']} ms ({g['count']} requests)"),
        (f"  the same directly on CAN (can-isotp)           p50 {d['p50_ms']} / p99 "
         f"{d['p99_ms']} / max {d['max_ms']} ms: gateway / direct {r['ratio_p50']}x p50, "
         f"{r['ratio_p99']}x p99"),
        (f"  requests per second through the gateway: 1 tester {r1['per_s']}/s, {r4['testers']} "
         f"testers {r4['per_s']}/s ({r4['busy_nacks']} NACK 0x06 target busy: one request per "
         "ECU at a time)"),
        (f"  gateway process: CPU {r['gateway_summary']['cpu_pct']} % of a core, step exec p50 "
         f"{r['gateway_summary']['exec_us']['p50_us']} us, bad inputs "
         f"{r['gateway_summary']['bad_input_total']}"),
    ])


if __name__ == "__main__":
    print(json.dumps(measure(Path(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]))))
