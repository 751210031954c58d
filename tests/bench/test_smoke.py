"""`vecu bench --quick` end to end in a real process: exit 0 and every group's figures printed,
`--only GROUP` for the groups that take a few seconds, the others together (the whole default
set, no --only, runs from the installed wheel in .ci/wheel-smoke). Each run has a time limit and is
killed with everything it started (vecu.live.children) when it overruns."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from vecu.live.children import run_bounded
from vecu.live.netns import namespace_prefix

NUM = r"[0-9]+(?:\.[0-9]+)?"
FULL_TIMEOUT_S = 240.0  # ~30 s on an idle 2-core machine; the limit is for a loaded one
GROUP_TIMEOUT_S = 90.0

# what each group prints, with numbers where the figures go
EXPECTED = {
    "ukf": [rf"^\s+arm\s+\d+\s+{NUM}\s+{NUM}\s+{NUM}x",
            rf"speed KF \(plain floats\)\s+{NUM} us",
            rf"^\s+sdkf\s+{NUM} us\s+vs {NUM} us",
            rf"manifold SDKF \+ 6-event CAC prediction\s+{NUM} us"],
    "bus": [rf"Virtual bus send\+recv: vecu {NUM} us vs python-can VirtualBus {NUM} us"],
    "pipeline": [rf"pipeline \(no log\)\s+{NUM}x real time\s+\({NUM} us/tick: estimator {NUM}",
                 rf"vecu run pipeline \(with \.blf\)\s+{NUM}x real time",
                 rf"vecu run --duration {NUM} \(numba kernels\): {NUM}x real time \(target >= 25x",
                 rf"vecu run --duration {NUM} \(python kernels\): {NUM}x real time \(target >= 20x",
                 rf"throttle estimator alone: {NUM} us/tick \(target <= 4 us: (met|not met)\) -> no pipeline running it beats {NUM}x",
                 r"1 shipped scenarios \(\w+ kernels\): [0-9.]+ s wall, 1 passed",
                 rf"peak RSS of `vecu run --log x.log`, fresh process each: {NUM} s: \d+ kB"],
    "ecu": [rf"{NUM} us/tick = {NUM}x real time \(target <= 30 us/tick: (met|not met)\)",
            rf"cantools-only encode/decode: {NUM} us/tick"],
    "breakdown": [rf"{NUM}x real time, {NUM} us/tick",
                  rf"estimator: throttle production PF/KF\s+{NUM}", rf"bus: send\s+{NUM}"],
    "kernels": [rf"(x real time vs {NUM}x|Compiled kernels: skipped)",
                (rf"(particle filter alone: {NUM} us/tick vs {NUM} us/tick \({NUM}x; target <= 4 "
                 rf"us/tick: (met|not met)\)|Compiled kernels: skipped)")],
    "replay": [rf"drive\.blf\s+\d+ frames\s+{NUM}x real time",
               r"drive\.log .* target >= 50% of the bare reading speed: (met|not met)",
               (rf"ceiling: reading \({NUM} us per ms of trace\) plus the throttle estimator alone "
                rf"\({NUM} us/tick\) allow at most {NUM}x"),
               rf"vecu replay\s+schedule error p50 {NUM} us"],
    "live": [rf"baseline: bare 1 ms WallClock loop, tick jitter p50 {NUM}",
             r"throughput, virtual bus, one process: offered \d+ frames/s",
             rf"memory: {NUM} simulated min \({NUM}x real time\): RSS \d+ kB"],
    "uds": [rf"RDBI 0x0100 \(single frame\)\s+p50 {NUM} / p99 {NUM} / max {NUM} ms",
            rf"RDBI 0xF190 VIN \(multi-frame\)\s+p50 {NUM} / p99 {NUM} / max {NUM} ms",
            rf"bare ISO-TP echo on the same clock and 1 ms tick: 5 B p50 {NUM}",
            # on the simulated clock: every tick of the request window broadcast, 1 ms apart
            (r"simulated clock .*\n(?:.*\n){3}.*during the requests \(.*\): (\d+) frames heard "
            r"over \1 ECU ticks, 0 ticks lost, largest gap 1\.0 ms, 0 overruns"),
            r"live, wall clock(?:.*\n){4}.*during the requests \(.*\): \d+ frames heard"],
    "restbus": [rf"vecu restbus \(all at once\) period error p50 {NUM} / p99 {NUM} / max {NUM} us",
                rf"python-can send_periodic period error p50 {NUM} / p99 {NUM}",
                r"simulated clock: .* periods exact: True"],
}
CAMPAIGN = (rf"batch engine {NUM} s/run .*\n  campaign {NUM} s = {NUM} s/run: {NUM}x sequential "
            r"`vecu eval manifold`")
LIVE_UDP = rf"ECU in its own process \(udp_multicast, {NUM} s\): tick jitter p50 {NUM}"
# a fault-free run on a loaded host, without and with catch-up and --realtime
LOADED = [rf"fault-free run under 3 busy processes, {w} catch-up and --realtime \(.*\): \d+ "
          rf"false DTCs in {NUM} s = {NUM} per hour; plant ticks skipped \d+, late \d+"
          for w in ("without", "with")]
FAST_GROUPS = ("bus", "pipeline", "ecu", "breakdown", "kernels", "uds", "restbus")  # a few seconds each


def _bench(*args: str, timeout: float) -> str:
    try:
        res = run_bounded([sys.executable, "-m", "vecu", "bench", "--quick", *args],
                          timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"vecu bench --quick {' '.join(args)} took more than {timeout:.0f} s")
    assert res.returncode == 0, (f"exit {res.returncode}\n{res.stdout[-2000:]}\n"
                                 f"{res.stderr[-3000:]}")
    return res.stdout


def _missing(out: str, groups: tuple[str, ...]) -> list[str]:
    return [f"{g}: {pat}" for g in groups for pat in EXPECTED[g]
            if not re.search(pat, out, re.MULTILINE)]


SLOW_GROUPS = tuple(g for g in EXPECTED if g not in FAST_GROUPS)  # ukf, replay, live


def test_bench_quick_slow_groups_together():
    out = _bench("--only", ",".join(SLOW_GROUPS), timeout=FULL_TIMEOUT_S)
    missing = _missing(out, SLOW_GROUPS)
    assert not missing, "\n".join(missing) + "\n" + out
    if namespace_prefix()[0] is not None:  # else the live group reports the udp runs skipped
        assert re.search(LIVE_UDP, out), out
        assert all(re.search(p, out) for p in LOADED), out
    else:
        assert "skipped" in out


@pytest.mark.parametrize("group", FAST_GROUPS)
def test_bench_quick_only(group):
    out = _bench("--only", group, timeout=GROUP_TIMEOUT_S)
    missing = _missing(out, (group,))
    assert not missing, "\n".join(missing) + "\n" + out
    others = [g for g in EXPECTED if g != group and g != "kernels"
              and all(re.search(p, out, re.MULTILINE) for p in EXPECTED[g])]
    assert not others, f"--only {group} also ran {others}"


FLEET = (rf"--workers 2 {NUM} s incl\. cluster start \({NUM}x\): ratio {NUM} .*\n"
         r"  results identical: rows True, output traces True; verdicts \{'pass': 3\}, errors 0")


@pytest.mark.slow
def test_bench_quick_fleet_group():
    """--only fleet (not in the default set: minutes at full size): drives recorded and replayed
    one by one and on a LocalCluster of 2 workers, the same rows and output traces."""
    out = _bench("--only", "fleet", timeout=FULL_TIMEOUT_S)
    assert re.search(FLEET, out), out


def test_bench_quick_campaign_group():
    """--only campaign (not in the default set: minutes at full size) on a real LocalCluster."""
    out = _bench("--only", "campaign", timeout=GROUP_TIMEOUT_S)
    assert re.search(CAMPAIGN, out), out


GATEWAY = [rf"RDBI 0x0100 through the gateway \(doipclient\)\s+p50 {NUM} / p99 {NUM}",
           (rf"the same directly on CAN \(can-isotp\)\s+p50 {NUM} / p99 {NUM} / max {NUM} ms: "
            rf"gateway / direct {NUM}x p50, {NUM}x p99"),
           rf"requests per second through the gateway: 1 tester {NUM}/s, 4 testers {NUM}/s",
           r"gateway process: .* bad inputs 0"]
ROUTING = [(rf"taken, routed and sent by the gateway's step\s+{NUM} frames/s; python-can recv "
            rf"alone {NUM} frames/s: {NUM}x"),
           rf"routes\[0\] src->dst latency .* min/mean/p99/max {NUM}/{NUM}/{NUM}/{NUM} us",
           r"can-gw beside vecu: skipped: no SocketCAN|vcan0 -> vcan1 on this kernel"]


def test_bench_quick_gateway_group():
    """--only gateway (not in the default set: live processes in a namespace): two ECUs and the
    gateway, the same request through DoIP and directly on CAN in one run; the routing between
    buses against a bare python-can receive."""
    out = _bench("--only", "gateway", timeout=GROUP_TIMEOUT_S)
    missing = [p for p in ROUTING if not re.search(p, out)]  # in-process: everywhere
    assert not missing, "\n".join(missing) + "\n" + out
    if namespace_prefix()[0] is None:
        assert "Gateway (DoIP -> CAN): skipped" in out
        return
    missing = [p for p in GATEWAY if not re.search(p, out)]
    assert not missing, "\n".join(missing) + "\n" + out
