"""Inside a private network namespace: `vecu ecu` and `vecu plant` on udp_multicast, and a
udsoncan tester over can-isotp reading the VIN, the live throttle and the TPS DTC after a kill,
clearing it, unlocking security and forcing a sensor value. Prints one JSON line.
Run by tests/live/test_uds_live.py (python tests/live/uds_live_tester.py OUTDIR)."""

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
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"
INTERFACE, CHANNEL = "udp_multicast", GROUP  # argv 2, 3: e.g. socketcan vcan0
BUS = ["--interface", INTERFACE, "--channel", CHANNEL]


def main(out: Path) -> dict:
    vecu = [sys.executable, "-m", "vecu"]
    procs = []
    res: dict = {}
    try:
        procs += start_ecu_and_plant(out, BUS, ("--tps-timeout-cycles=100",))
        bus = can.Bus(interface=INTERFACE, channel=CHANNEL)
        stack = isotp.CanStack(bus, address=isotp.Address(
            isotp.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8))
        config = {**CLIENT_CONFIG, "dtc_snapshot_did_size": 2}
        with Client(PythonIsoTpConnection(stack), config=config) as c:
            await_ecu(c)  # until the ECU ticks (it syncs to the plant's first frames)
            t0 = time.perf_counter()
            res["vin"] = c.read_data_by_identifier(0xF190).service_data.values[0xF190]
            res["latency_ms"] = (time.perf_counter() - t0) * 1e3
            live = c.read_data_by_identifier([0x0100, 0x0103, 0x0105]).service_data.values
            res["live"] = {f"{k:04X}": v for k, v in live.items()}
            subprocess.run([*vecu, "inject", *BUS, "--target", "tps", "--kind", "dead",
                            "--quiet"], check=True, timeout=60)
            time.sleep(0.5)
            dtcs = c.get_dtc_by_status_mask(0x08).service_data.dtcs
            res["confirmed"] = [[d.id, d.status.get_byte_as_int()] for d in dtcs]
            snap = c.get_dtc_snapshot_by_dtc_number(0x012200, 1).service_data.dtcs[0]
            res["snapshot"] = {f"{s.did:04X}": s.data for s in snap.snapshots}
            c.clear_dtc(0xFFFFFF)
            res["after_clear"] = [d.id for d in c.get_dtc_by_status_mask(0x08).service_data.dtcs]
            subprocess.run([*vecu, "inject", *BUS, "--target", "tps", "--kind", "clear",
                            "--quiet"], check=True, timeout=60)
            time.sleep(1.0)  # the TPS is trusted again after 500 ms of clean frames
            c.change_session(3)
            c.unlock_security_access(1)
            c.io_control(0x0104, control_param=3, values=[4.99])  # above the short-circuit limit
            time.sleep(0.3)
            forced = c.read_data_by_identifier([0x0104, 0x0105]).service_data.values
            res["forced"] = [forced[0x0104], forced[0x0105]]
            c.io_control(0x0104, control_param=0)
        bus.shutdown()
    finally:
        stop_all(procs, signal.SIGTERM, 30.0)
    summary = json.loads((out / "ecu.json").read_text()) if (out / "ecu.json").exists() else {}
    res["uds"] = summary.get("uds")
    res["lost_throttle_estimates"] = summary.get("lost_throttle_estimates")
    return res


if __name__ == "__main__":
    if len(sys.argv) > 3:
        INTERFACE, CHANNEL = sys.argv[2], sys.argv[3]
        BUS[:] = ["--interface", INTERFACE, "--channel", CHANNEL]
    print(json.dumps(main(Path(sys.argv[1]))))
