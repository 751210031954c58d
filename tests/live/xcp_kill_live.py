"""Inside a private network namespace: `vecu ecu` and `vecu plant` on udp_multicast, and a raw
XCP master (python-can, no XCP library) sending the eleven frames that used to stop the ECU
(CONNECT, GET_ID 0, a DAQ list with one 4-byte entry at 0x00F00008 in the GET_ID area, started,
then GET_ID 1 or GET_DAQ_EVENT_INFO 0), each variant once; after each it counts the
ECU_ThrottleEstimate frames on the bus (decoded) for a second and asks CONNECT and GET_STATUS.
Prints one JSON line. Run by tests/live/test_xcp_live.py
(python tests/live/xcp_kill_live.py OUTDIR)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.live.pair import ecu_summary, start_ecu_and_plant
from tests.xcp.test_boundary import CONNECT, GET_STATUS, eleven_frames
from vecu.codec import DbcCodec
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"  # the namespace routes this group (vecu.live.netns)
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
MASTER, SLAVE = 0x7F0, 0x7F1


class Raw:
    def __init__(self) -> None:
        self.bus = can.Bus(interface="udp_multicast", channel=GROUP)
        self.est = DbcCodec()["ECU_ThrottleEstimate"]
        self.estimates: list[dict[str, float]] = []

    def _take(self, msg: can.Message) -> bytes | None:
        if msg.arbitration_id == self.est.frame_id:
            self.estimates.append(self.est.decode(msg.data))
        elif msg.arbitration_id == SLAVE and msg.data and msg.data[0] >= 0xFC:
            return bytes(msg.data)
        return None

    def ask(self, cto: bytes, timeout: float = 1.0) -> str | None:
        """The slave's answer to one command (hex), None after `timeout`."""
        self.bus.send(can.Message(arbitration_id=MASTER, data=cto, is_extended_id=False))
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = self.bus.recv(left)
            if msg is not None and (answer := self._take(msg)) is not None:
                return answer.hex()
        return None

    def listen(self, seconds: float) -> list[dict[str, float]]:
        """The estimates decoded from the bus in the next `seconds`."""
        self.estimates = []
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            msg = self.bus.recv(left)
            if msg is not None:
                self._take(msg)
        return self.estimates


def main(out: Path) -> dict:
    procs: list[subprocess.Popen] = []
    res: dict = {"variants": {}}
    try:
        procs += start_ecu_and_plant(out, BUS, ecu_s=90, plant_s=80)
        raw = Raw()
        for _ in range(60):  # until the ECU ticks (it syncs to the plant's first frames)
            if raw.ask(CONNECT, 0.5) is not None:
                break
        for name, last in (("get_id_1", bytes([0xFA, 0x01])),
                           ("get_daq_event_info_0", bytes([0xD7, 0, 0, 0]))):
            answers = [raw.ask(cto) for cto in eleven_frames(last)]
            estimates = raw.listen(1.0)
            res["variants"][name] = {
                "answers": answers, "estimates_per_s": len(estimates),
                "estimates_ok": all(math.isfinite(e["THR_AngleEst"])
                                    and 0.0 <= e["THR_AngleEst"] <= 90.0 for e in estimates),
                "connect": raw.ask(CONNECT), "status": raw.ask(GET_STATUS),
                "ecu_alive": procs[0].poll() is None}
        raw.ask(bytes([0xFE]))
        raw.bus.shutdown()
    finally:
        res["exit_codes"] = stop_all(procs, signal.SIGTERM, 30.0)
    summary, res["ecu_runs_share"] = ecu_summary(out)
    res["xcp"] = summary.get("xcp")
    return res


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
