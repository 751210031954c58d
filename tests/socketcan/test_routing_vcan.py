"""A frame route through `vecu gateway` beside the kernel's can-gw on a real kernel: cangen
sends 0x123 on vcan0, vecu routes it to vcan1 as 0x421 and `cangw -A -s vcan0 -d vcan1 -f
123:7FF -m SET:I:321...` as 0x321, one candump on both interfaces timestamps all three. Every frame
arrives through both, payload untouched; the latencies of both, from the same candump timestamps
in the same run, are printed with their ratio (behaviour asserted, not timing: the emulated
guest runs Python ~20x slower)."""

from __future__ import annotations

import signal
import statistics
import subprocess

from tests.socketcan.kernel import Processes, needs_kernel, summary, tool, wait_for

pytestmark = needs_kernel
FRAMES = 40
CONFIG = """
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
CANGW_RULE = ["-s", "vcan0", "-d", "vcan1", "-f", "123:7FF", "-m",
              "SET:I:321.0.0000000000000000"]


def _candump(path) -> list[tuple[float, str, int, str]]:
    """(time, interface, CAN ID, payload hex) of each line of `candump -L`."""
    rows = []
    for line in path.read_text().splitlines():
        stamp, iface, frame = line.split()[:3]
        can_id, _, data = frame.partition("#")
        rows.append((float(stamp.strip("()")), iface, int(can_id, 16), data.lower()))
    return rows


def test_a_frame_route_beside_can_gw(tmp_path):
    procs = Processes(tmp_path)
    (tmp_path / "gw.toml").write_text(CONFIG)
    try:
        tool("cangw", "-A", *CANGW_RULE)
        procs.start("candump", ["candump", "-L", "vcan0", "vcan1"],
                    stdout=tmp_path / "candump.log")
        procs.vecu("gateway", "gateway", "--config", str(tmp_path / "gw.toml"), "--doip-port",
                   "0", "--no-status", "--ready-file", str(tmp_path / "gw.ready"), "--summary",
                   str(tmp_path / "gw.json"), "--quiet")
        procs.ready("gateway", tmp_path / "gw.ready")
        tool("cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "20", "-n", str(FRAMES))
        wait_for(lambda: (tmp_path / "candump.log").read_text().count(" vcan1 421#") >= FRAMES,
                 120.0, 0.5)
        assert procs.stop("gateway") == 0, procs.stderr("gateway")
        procs.stop("candump", signal.SIGINT)
    finally:
        procs.close()
        subprocess.run(["cangw", "-D", *CANGW_RULE], check=False, capture_output=True)
    rows = _candump(tmp_path / "candump.log")
    sent = [(t, data) for t, iface, i, data in rows if iface == "vcan0" and i == 0x123]
    assert len(sent) == FRAMES and len({d for _, d in sent}) == FRAMES  # cangen -D i: distinct
    lat = {}
    for out_id in (0x421, 0x321):
        got = [(t, data) for t, iface, i, data in rows if iface == "vcan1" and i == out_id]
        assert [d for _, d in got] == [d for _, d in sent], hex(out_id)  # all, in order, untouched
        lat[out_id] = [(tg - ts) * 1e6 for (ts, _), (tg, _) in zip(sent, got)]
        assert min(lat[out_id]) >= 0
    vecu_us, gw_us = (statistics.median(lat[0x421]), statistics.median(lat[0x321]))
    route = summary(tmp_path / "gw.json")["routing"]["routes"]["routes[0] src->dst"]
    assert route["in"] == route["out"] == FRAMES
    print(f"\nlatency from one candump, median: vecu {vecu_us:.0f} us, can-gw {gw_us:.0f} us, "
          f"ratio {vecu_us / max(gw_us, 1e-3):.0f}x (vecu p99 {route['latency_us']['p99']} us "
          f"by its own count)")
