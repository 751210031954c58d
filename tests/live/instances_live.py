"""Inside a private network namespace: two `vecu ecu` processes on one udp_multicast bus,
instance 0 (throttle + manifold) and instance 1 (throttle + speed + steering), and one plant.
A udsoncan tester reads each one's serial and, after `vecu inject` kills the TPS, each one's
DTCs at its own IDs; a listener collects the frames on the bus. Prints one JSON line.
Run by tests/live/test_instances_live.py (python tests/live/instances_live.py OUTDIR)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import isotp
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.live.pair import await_ecu, start_ecu_and_plant
from tests.uds.sim import CLIENT_CONFIG
from vecu.instances import uds_ids
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
ECUS = {0: ("--no-speed", "--no-steering"), 1: ("--instance", "1", "--no-manifold")}


def ask(bus: can.BusABC, instance: int, work):
    ids = uds_ids(instance)
    stack = isotp.CanStack(bus, address=isotp.Address(
        isotp.AddressingMode.Normal_11bits, txid=ids["request_id"], rxid=ids["response_id"]))
    with Client(PythonIsoTpConnection(stack), config=CLIENT_CONFIG) as c:
        await_ecu(c)  # until the ECU ticks (it syncs to the plant's first frames)
        return work(c)


def main(out: Path) -> dict:
    vecu = [sys.executable, "-m", "vecu"]
    args = {n: (*a, "--tps-timeout-cycles=100", "--set", f"ecu.uds.serial=VECU-0000{n}")
            for n, a in ECUS.items()}
    procs = []
    res: dict = {}
    try:
        procs += start_ecu_and_plant(out, BUS, args[0], ecu_s=60, plant_s=50,
                                     more_ecus=(args[1],))
        bus = can.Bus(interface="udp_multicast", channel=GROUP)
        listener = can.Bus(interface="udp_multicast", channel=GROUP)
        res["serial"] = {n: ask(bus, n, lambda c: c.read_data_by_identifier(0xF18C)
                                .service_data.values[0xF18C]) for n in ECUS}
        while listener.recv(0) is not None:  # from now on
            pass
        end = time.monotonic() + 1.0
        ids: dict[int, int] = {}
        while time.monotonic() < end:
            msg = listener.recv(0.1)
            if msg is not None:
                ids[msg.arbitration_id] = ids.get(msg.arbitration_id, 0) + 1
        res["ids"] = {f"0x{k:X}": v for k, v in sorted(ids.items())}
        subprocess.run([*vecu, "inject", *BUS, "--target", "tps", "--kind", "dead", "--quiet"],
                       check=True, timeout=60)
        time.sleep(0.5)
        res["dtcs"] = {n: ask(bus, n, lambda c: [d.id for d in c.get_dtc_by_status_mask(0x08)
                                                 .service_data.dtcs]) for n in ECUS}
        listener.shutdown()
        bus.shutdown()
    finally:
        stop_all(procs, signal.SIGTERM, 30.0)
    for n, name in ((0, "ecu.json"), (1, "ecu1.json")):
        path = out / name
        summary = json.loads(path.read_text()) if path.exists() else {}
        res[f"summary{n}"] = {k: summary.get(k) for k in ("instance", "can_ids", "uds")}
    return res


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
