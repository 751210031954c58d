"""Inside a private network namespace: `vecu gateway` joins two udp_multicast buses (one group,
two ports) and routes between them: ECU_SpeedEstimate frames sent on "powertrain" arrive on
"vehicle" under a new ID with their payload untouched, and repacked into VEH_Dynamics with the
speed in m/s. Prints one JSON line. Run by tests/gateway/test_routing_live.py
(python tests/gateway/routing_live_tester.py OUTDIR)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import cantools

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from vecu.codec import builtin_dbc_path
from vecu.live.options import UDP_DEFAULT_GROUP

HERE = Path(__file__).resolve().parent
PT, VEH = 43113, 43114  # one multicast group, a port per bus
FRAMES = 200
CONFIG = f'''
[buses.powertrain]
interface = "udp_multicast"
channel = "{UDP_DEFAULT_GROUP}"
port = {PT}
dbc = ["vecu"]

[buses.vehicle]
interface = "udp_multicast"
channel = "239.74.163.99"  # a group the namespace does not route: --bus gives the one it does
port = {VEH}
dbc = ["body.dbc"]

[[routes]]
from = "powertrain"
to = "vehicle"
messages = ["ECU_SpeedEstimate"]
id = 0x420

[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Dynamics"
send = "on_change"
signals = {{ VEH_Speed = "ECU_SpeedEstimate.SPD_VehSpeed" }}
'''


def main(out: Path) -> dict:
    shutil.copy(HERE / "data" / "body.dbc", out / "body.dbc")
    (out / "gw.toml").write_text(CONFIG)
    vecu_db = cantools.database.load_file(str(builtin_dbc_path()))
    body = cantools.database.load_file(str(HERE / "data" / "body.dbc"))
    spd = vecu_db.get_message_by_name("ECU_SpeedEstimate")
    pt = can.Bus(interface="udp_multicast", channel=UDP_DEFAULT_GROUP, port=PT)
    veh = can.Bus(interface="udp_multicast", channel=UDP_DEFAULT_GROUP, port=VEH)
    gw = subprocess.Popen(  # the vehicle bus's group from --bus
        [sys.executable, "-m", "vecu", "gateway", "--config", str(out / "gw.toml"), "--bus",
         f"vehicle=udp_multicast:{UDP_DEFAULT_GROUP}", "--doip-port", "0", "--duration", "60",
         "--ready-file", str(out / "gw.ready"), "--summary", str(out / "gw.json")],
        stdout=subprocess.PIPE, stderr=open(out / "gw.err", "w"), text=True)  # noqa: SIM115
    try:
        end = time.monotonic() + 60
        while not (out / "gw.ready").exists() and time.monotonic() < end:
            time.sleep(0.1)
        time.sleep(0.3)
        sent = []
        got: dict[str, list] = {"420": [], "500": []}

        def drain(timeout: float) -> None:
            while (m := veh.recv(timeout)) is not None:
                if m.arbitration_id in (0x420, 0x500):
                    key = f"{m.arbitration_id:X}"
                    got[key].append(bytes(m.data).hex() if key == "420" else
                                    body.decode_message(0x500, bytes(m.data))["VEH_Speed"])
                if len(got["420"]) >= FRAMES:
                    return
        for i in range(FRAMES):
            data = spd.encode({s.name: 0 for s in spd.signals} | {"SPD_VehSpeed": 10.0 + i * 0.5})
            pt.send(can.Message(arbitration_id=spd.frame_id, data=data, is_extended_id=False))
            sent.append(data.hex())
            time.sleep(0.002)
            drain(0.0)  # as they come: the socket's buffer holds a few hundred frames
        drain(5.0)  # a loaded machine: the gateway may lag
        gw.send_signal(signal.SIGTERM)
        stdout, _ = gw.communicate(timeout=30)
    finally:
        if gw.poll() is None:
            gw.kill()
        pt.shutdown()
        veh.shutdown()
    summary = json.loads((out / "gw.json").read_text())
    return {"sent": sent, "routed": got["420"], "speeds": got["500"], "stdout": stdout,
            "returncode": gw.returncode, "routing": summary["routing"],
            "stopped_by": summary["stopped_by"]}


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
