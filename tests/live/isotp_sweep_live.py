"""Inside a private network namespace: `vecu ecu` alone on udp_multicast, and two testers that
send ISO-TP requests as fast as its flow control allows (STmin 0): can-isotp's threaded stack
and scapy's ISOTPSoftSocket on python-can. Every requested length gets the answer of
tests/uds/isotp_sweep.py or is listed as wrong. Prints one JSON line.

python tests/live/isotp_sweep_live.py OUTDIR FIRST LAST STEP (lengths range(FIRST, LAST+1, STEP)
plus the boundaries of single frame, first block and the 4095 maximum)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.uds.isotp_sweep import MAX_LENGTH, expected, request

GROUP = "239.74.163.2"
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
BOUNDARIES = [1, 2, 6, 7, 8, 13, 14, 15, 33, 34, 35, 118, 119, 120, 1000, 2000, 4093, 4094, 4095]


def lengths(first: int, last: int, step: int) -> list[int]:
    return sorted({*range(first, last + 1, step), *(b for b in BOUNDARIES if b <= MAX_LENGTH)})


def with_can_isotp(todo: list[int]) -> tuple[dict[int, str], float]:
    import can
    import isotp

    bus = can.Bus(interface="udp_multicast", channel=GROUP)
    stack = isotp.CanStack(bus, address=isotp.Address(
        isotp.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8),
        params={"stmin": 0, "blocksize": 0, "tx_padding": 0xCC})
    stack.start()
    wrong: dict[int, str] = {}
    t0 = time.perf_counter()
    try:
        for n in todo:
            stack.send(request(n))
            got = stack.recv(block=True, timeout=2.0)
            if got is None or bytes(got) != expected(n):
                wrong[n] = "no response" if got is None else bytes(got)[:8].hex()
    finally:
        stack.stop()
        bus.shutdown()
    return wrong, time.perf_counter() - t0


def with_scapy(todo: list[int]) -> tuple[dict[int, str], float]:
    from scapy.config import conf

    conf.contribs["CANSocket"] = {"use-python-can": True}
    conf.contribs["ISOTP"] = {"use-can-isotp-kernel-module": False}
    from scapy.contrib.cansocket_python_can import PythonCANSocket
    from scapy.contrib.isotp import ISOTP, ISOTPSoftSocket

    wrong: dict[int, str] = {}
    t0 = time.perf_counter()
    with ISOTPSoftSocket(PythonCANSocket(interface="udp_multicast", channel=GROUP),
                         tx_id=0x7E0, rx_id=0x7E8, padding=True) as sock:
        for n in todo:
            got = sock.sr1(ISOTP(request(n)), timeout=2.0, verbose=False)
            if got is None or bytes(got.data) != expected(n):
                wrong[n] = "no response" if got is None else bytes(got.data)[:8].hex()
    return wrong, time.perf_counter() - t0


def main(out: Path, first: int, last: int, step: int) -> dict:
    todo = lengths(first, last, step)
    ecu = subprocess.Popen(
        [sys.executable, "-m", "vecu", "ecu", *BUS, "--sync-timeout", "0", "--duration", "1800",
         "--no-speed", "--no-steering", "--no-manifold", "--quiet", "--summary",
         str(out / "ecu.json"), "--ready-file", str(out / "ecu.ready")],
        stderr=open(out / "ecu.err", "w"))  # noqa: SIM115 (the child owns it)
    res: dict = {"lengths": len(todo)}
    try:
        for _ in range(600):
            if (out / "ecu.ready").exists():
                break
            time.sleep(0.1)
        time.sleep(0.5)
        for name, client in (("can-isotp", with_can_isotp), ("scapy", with_scapy)):
            wrong, took = client(todo)
            res[name] = {"wrong": {str(k): v for k, v in wrong.items()}, "seconds": round(took, 1)}
    finally:
        ecu.send_signal(signal.SIGTERM)
        try:
            ecu.wait(30)
        except subprocess.TimeoutExpired:
            ecu.kill()
    summary = json.loads((out / "ecu.json").read_text()) if (out / "ecu.json").exists() else {}
    res["uds"] = summary.get("uds")
    res["ticks"] = summary.get("ticks", {}).get("ecu")
    res["lost_throttle_estimates"] = summary.get("lost_throttle_estimates")
    return res


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]), *(int(a) for a in sys.argv[2:5]))))
