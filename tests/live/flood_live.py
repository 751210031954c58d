"""Inside a private network namespace: `vecu plant` + `vecu ecu` on udp_multicast, then 100,000
frames as fast as python-can sends them (bad sensor frames and unknown IDs), while a listener
counts the ECU's estimates; after the flood a udsoncan tester reads the VIN. Prints one JSON
line. Run by tests/live/test_flood_live.py (python tests/live/flood_live.py OUTDIR)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import isotp
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection
from udsoncan.exceptions import TimeoutException

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.live.pair import start_ecu_and_plant
from tests.uds.sim import CLIENT_CONFIG
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
FLOOD = 100_000
# what floods: a TPS frame with a wrong CRC, a short wattmeter frame, an ID nobody knows
FLOOD_FRAMES = (can.Message(arbitration_id=0x100, data=bytes(4), is_extended_id=False),
                can.Message(arbitration_id=0x101, data=bytes(3), is_extended_id=False),
                can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False))


def _listen(stop: threading.Event, seen: list[float]) -> None:
    """The ECU's throttle estimates (0x200), with the listener's clock."""
    bus = can.Bus(interface="udp_multicast", channel=GROUP, can_filters=[
        {"can_id": 0x200, "can_mask": 0x7FF, "extended": False}])
    try:
        while not stop.is_set():
            msg = bus.recv(0.1)
            if msg is not None and msg.arbitration_id == 0x200:
                seen.append(time.monotonic())
    finally:
        bus.shutdown()


def main(out: Path) -> dict:
    procs: list[subprocess.Popen] = []
    res: dict = {}
    stop = threading.Event()
    seen: list[float] = []
    try:
        procs = start_ecu_and_plant(out, BUS, plant_s=110,
                                    plant_args=("--summary", str(out / "plant.json")))
        listener = threading.Thread(target=_listen, args=(stop, seen), daemon=True)
        listener.start()
        time.sleep(2.0)  # the ECU runs on the plant's frames
        n_before = len(seen)
        t0 = time.monotonic()  # the flood in its own process: the listener keeps its GIL
        flood = subprocess.run([sys.executable, __file__, "--flood", str(FLOOD)],
                               capture_output=True, text=True, timeout=120, check=True)
        t1 = time.monotonic()
        sent, seconds = (float(x) for x in flood.stdout.split())
        res["flood"] = {"frames": int(sent), "seconds": round(seconds, 3),
                        "per_s": round(sent / max(seconds, 1e-9))}
        t0 = t1 - seconds
        time.sleep(0.3)
        during = [t for t in seen[n_before:] if t0 <= t <= t1 + 0.3]
        res["estimates_during_flood"] = len(during)
        bus = can.Bus(interface="udp_multicast", channel=GROUP)  # after the flood: no backlog
        stack = isotp.CanStack(bus, address=isotp.Address(
            isotp.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8))
        with Client(PythonIsoTpConnection(stack), config={**CLIENT_CONFIG, "p2_timeout": 5.0}) as c:
            t2 = time.monotonic()
            try:
                res["vin"] = c.read_data_by_identifier(0xF190).service_data.values[0xF190]
            except TimeoutException:
                res["vin"] = None
            res["uds_after_flood_s"] = round(time.monotonic() - t2, 3)
        time.sleep(1.0)
        after = len(seen)
        time.sleep(1.0)
        res["estimates_per_s_after"] = len(seen) - after
        bus.shutdown()
    finally:
        stop.set()
        res["exit_codes"] = stop_all(procs, signal.SIGTERM, 30.0)
    for name in ("ecu", "plant"):
        path = out / f"{name}.json"
        res[name] = json.loads(path.read_text()) if path.exists() else None
    (out / "result.json").write_text(json.dumps(res, indent=1))  # the evidence, kept
    return res


def flood(n: int) -> None:
    """n frames as fast as python-can sends them; prints 'sent seconds'."""
    bus = can.Bus(interface="udp_multicast", channel=GROUP)
    sent = 0
    t0 = time.monotonic()
    for i in range(n):
        try:
            bus.send(FLOOD_FRAMES[i % 3])
            sent += 1
        except can.CanError:
            pass
    print(sent, time.monotonic() - t0)
    bus.shutdown()


if __name__ == "__main__":
    if sys.argv[1] == "--flood":
        flood(int(sys.argv[2]))
    else:
        print(json.dumps(main(Path(sys.argv[1]))))
