"""A frame route through `vecu gateway` beside the kernel's can-gw on a real kernel
(vecu.bench.routing.kernel_comparison): cangen sends 0x123 on vcan0, vecu routes it to vcan1 as
0x421 and `cangw -A -s vcan0 -d vcan1 -f 123:7FF -m SET:I:321...` as 0x321, one candump on both
interfaces timestamps all three. Every frame arrives through both, in order, payload untouched;
the latencies of both, from the same candump timestamps in the same run, are printed with
their ratio (behaviour asserted, not timing: the emulated guest runs Python ~20x slower)."""

from __future__ import annotations

from tests.socketcan.kernel import needs_kernel
from vecu.bench.routing import kernel_comparison

pytestmark = needs_kernel
FRAMES = 40


def test_a_frame_route_beside_can_gw(tmp_path):
    r = kernel_comparison(tmp_path, FRAMES)
    assert r["gateway_exit"] == 0
    sent = [d for _, d in r["sent"]]
    assert len(sent) == FRAMES and len(set(sent)) == FRAMES  # cangen -D i: each payload its own
    for name in ("vecu", "can_gw"):
        assert [d for _, d in r[name]] == sent, name  # every frame, in order, untouched
        assert all(tg >= ts for (ts, _), (tg, _) in zip(r["sent"], r[name])), name
    route = r["routing"]["routes"]["routes[0] src->dst"]
    assert route["in"] == route["out"] == FRAMES
    print(f"\nvcan0 -> vcan1 from one candump, median latency: vecu {r['vecu_median_us']} us, "
          f"can-gw {r['can_gw_median_us']} us, ratio {r['ratio']}x (vecu p99 "
          f"{route['latency_us']['p99']} us by its own count)")
