"""Inside a private network namespace: `vecu ecu` and `vecu plant` on udp_multicast, and a
pyxcp master that knows only the A2L `vecu a2l` wrote: it connects, records the throttle
estimate by DAQ on the 1 ms event, lowers the TPS plausibility debounce (300 -> 20) and sees
an implausible TPS confirmed within far less than the default 300 ms, and has an out-of-bounds
write refused. Prints one JSON line. Run by tests/live/test_xcp_live.py
(python tests/live/xcp_live_master.py OUTDIR)."""

from __future__ import annotations

import itertools
import json
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import can
import pya2l  # noqa: F401 - puts its generated modules on the path (before .parser)
from pya2l.parser import A2lParser
from pyxcp.config import set_application
from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
from pyxcp.master import Master
from pyxcp.types import XcpResponseError

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.live.pair import ecu_summary, start_ecu_and_plant
from tests.xcp.sim import master_config
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"  # the namespace routes this group (vecu.live.netns)
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
DEB = "ecu.throttle.tps_monitor.plaus_debounce"


class Collect(DaqOnlinePolicy):
    def __init__(self, lists):
        super().__init__(lists)
        self.rows = []

    def initialize(self):
        pass

    def finalize(self):
        pass

    def on_daq_list(self, daq_list, ts0, ts1, payload):
        self.rows.append((daq_list, ts1, list(payload)))


def from_a2l(path: Path) -> dict:
    """What the master knows: addresses, types and the CAN IDs, from the A2L only."""
    with A2lParser() as parser:
        module = parser.tree_from_a2l(path.read_bytes()).PROJECT.MODULE[0]
    out = {c.Name.Value: c.Address.Value for c in module.CHARACTERISTIC}
    out.update({m.Name.Value: m.ECU_ADDRESS.Address.Value for m in module.MEASUREMENT})
    can_blob = next(b.Generic for b in module.IF_DATA[0].Blob
                    if b.Generic.Name.Value == "XCP_ON_CAN")
    elements = list(can_blob.Element)
    for i, e in enumerate(elements):
        if e.HasField("Identifier") and e.Identifier.Value in ("CAN_ID_MASTER", "CAN_ID_SLAVE"):
            out[e.Identifier.Value] = elements[i + 1].Long.Value
    return out


def main(out: Path) -> dict:
    vecu = [sys.executable, "-m", "vecu"]
    procs = []
    res: dict = {}
    subprocess.run([*vecu, "a2l", "--out", str(out / "vecu.a2l")], check=True, timeout=120)
    a2l = from_a2l(out / "vecu.a2l")
    try:
        procs += start_ecu_and_plant(out, BUS, ("--tps-timeout-cycles=100",))
        app = master_config(a2l["CAN_ID_MASTER"], a2l["CAN_ID_SLAVE"], GROUP, timeout=2.0)
        set_application(app)
        daq = Collect([DaqList("throttle", 0, False, True, [
            ("throttle.estimate_deg", a2l["throttle.estimate_deg"], 0, "F32")])])
        bus = can.Bus(interface="udp_multicast", channel=GROUP)
        with Master("can", config=app, policy=daq, transport_layer_interface=bus) as m:
            for _ in range(60):  # until the ECU ticks (it syncs to the plant's first frames)
                try:
                    m.connect()
                    break
                except Exception:  # noqa: BLE001 - pyxcp's timeout
                    time.sleep(0.5)
            res["name"] = m.identifier(1)
            daq.setup()
            daq.start()
            t0 = time.perf_counter()
            time.sleep(3.0)
            daq.stop()
            wall = time.perf_counter() - t0
            stamps = [ts for _, ts, _ in daq.rows]
            res["daq_steps_ms"] = sorted({(b - a) / 1e6 for a, b in itertools.pairwise(stamps)})[:5]
            res["daq_samples_per_s"] = len(daq.rows) / wall
            res["daq_span_s"] = (stamps[-1] - stamps[0]) / 1e9 if stamps else 0.0
            res["daq_samples"] = len(daq.rows)
            res["daq_values_ok"] = all(-5.0 < row[2][0] < 95.0 for row in daq.rows)
            m.setMta(a2l[DEB])
            m.download(struct.pack("<i", 20))
            res["debounce"] = struct.unpack("<i", m.shortUpload(4, a2l[DEB]))[0]
            m.setMta(a2l[DEB])
            try:
                m.download(struct.pack("<i", 0))
                res["out_of_bounds"] = "accepted"
            except XcpResponseError as exc:
                res["out_of_bounds"] = str(exc.get_error_code())
            res["debounce_after_refusal"] = struct.unpack("<i", m.shortUpload(4, a2l[DEB]))[0]
            subprocess.run([*vecu, "inject", *BUS, "--target", "tps", "--kind", "gain",
                            "--value", "0.3", "--quiet"], check=True, timeout=60)
            time.sleep(3.0)  # the ECU's status changes are in its summary
            m.disconnect()
        bus.shutdown()
    finally:
        stop_all(procs, signal.SIGTERM, 30.0)
    summary, res["ecu_runs_share"] = ecu_summary(out)
    res["xcp"] = summary.get("xcp")
    res["detection"] = summary.get("throttle", {}).get("status_changes")
    res["lost_throttle_estimates"] = summary.get("lost_throttle_estimates")
    return res


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
