"""Live mode: plant, ECU and fault injector as separate processes (docs/live.md).

The multi-process tests run over udp_multicast inside a private network namespace (skipped when
the machine cannot make one); on SocketCAN, tests/socketcan/ (a real kernel). No timing
assertions: speed and jitter are for `vecu bench --only live`.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest

from vecu.cli import main as cli_main
from vecu.codec import DbcCodec
from vecu.live.livebus import LiveBus, sent_ids
from vecu.live.netns import namespace_prefix, python_module, run_in_namespace
from vecu.live.scenario import _wait_for
from vecu.live.sync import arrival_phase, start_instant
from vecu.stats import DurationHistogram

US = 1_000


def test_histogram_percentiles_are_those_of_the_sorted_values():
    h = DurationHistogram(limit_us=1_000)
    values_us = [5, 5, 7, 10, 10, 10, 50, 200, 999, 4_000]  # the last one above the limit
    for v in values_us:
        h.record(v * US + 300)  # 1 us bins: reported as the bin's upper edge
    s = h.summary()
    assert s["count"] == 10 and s["over_limit"] == 1
    assert s["p50_us"] == 11.0           # 5th smallest: 10.3 us -> bin [10, 11)
    assert s["p90_us"] == 1_000.0        # 9th: 999.3 us
    assert s["p99_us"] == s["max_us"] == 4_000.3  # in the overflow: the exact maximum
    assert h.fraction_above_us(100) == pytest.approx(0.3)
    assert DurationHistogram().summary()["p99_us"] is None


def test_arrival_phase_is_circular_and_the_grid_starts_after_the_late_edge():
    period = 1_000 * US
    # arrivals straddling the period boundary: 950 .. 1040 us, i.e. -50 .. +40 us around 0
    arrivals = [k * period + (950 + 10 * (k % 10)) * US for k in range(200)]
    mean, late = arrival_phase(arrivals, period, quantile=0.95)
    mean_wrapped = (mean + period / 2) % period - period / 2
    assert -10 * US < mean_wrapped < 0  # circular mean of -50..+40 us is -5 us
    assert 30 * US < late < 50 * US
    start = start_instant(mean, late, margin_ns=100 * US, now_perf_ns=123_456_789,
                          lead_ns=2 * period, period_ns=period)
    assert start >= 123_456_789 + 2 * period
    assert (start - (mean + late + 100 * US)) % period < US  # on the requested phase


def test_live_bus_drops_and_counts_own_echoes_but_passes_other_frames():
    codec = DbcCodec()
    ecu_raw = can.Bus(interface="virtual", channel="live-echo", receive_own_messages=True)
    plant_raw = can.Bus(interface="virtual", channel="live-echo")
    try:
        ecu = LiveBus(ecu_raw, sent_ids(codec, "VECU"), "virtual")
        est, watt = codec["ECU_ThrottleEstimate"], codec["ETB_Wattmeter"]
        ecu.send(est.frame({"THR_CRC": 0, "THR_AliveCounter": 0, "THR_Source": 0, "THR_Angle": 1.0,
                            "THR_AngleEst": 1.0, "THR_AngleEstStd": 1.0, "THR_TpsStatus": 0,
                            "THR_Validity": 1}, 0.0))
        plant_raw.send(watt.frame({"ETB_Voltage": 2.0, "ETB_Power": 3.0}, 0.0))
        # another node sending one of the ECU's IDs (a bus set-up error) is dropped as well, but
        # counted apart: it is not the ECU's own frame
        plant_raw.send(can.Message(arbitration_id=est.frame_id, data=bytes(8), is_extended_id=False))
        got = ecu.recv(1.0)
        assert got is not None and got.arbitration_id == watt.frame_id
        assert ecu.recv(0.2) is None
        counts = ecu.counts(codec)
        assert counts["own_echo"] == 1 and counts["foreign_own_id"] == 1
        assert counts["received"] == 1
        assert counts["rx_by_id"] == {"ETB_Wattmeter": 1}
        assert counts["tx_by_id"] == {"ECU_ThrottleEstimate": 1}
    finally:
        ecu_raw.shutdown()
        plant_raw.shutdown()


class _Frames(can.BusABC):
    """A bus that hands out given frames as an interface would deliver them."""

    def __init__(self, frames: list[can.Message]) -> None:
        super().__init__(channel="test")
        self.frames = list(frames)

    def send(self, msg, timeout=None) -> None:
        pass

    def _recv_internal(self, timeout):
        return (self.frames.pop(0) if self.frames else None), False


@pytest.mark.parametrize("interface,passed,echo,foreign", [
    # SocketCAN: python-can says is_rx=False for every frame of this host; none is the node's own
    ("socketcan", ["ETB_Wattmeter", "ETB_Wattmeter"], 0, 2),
    # udp_multicast: every frame comes back as is_rx=True; the node's IDs are its echo
    ("udp_multicast", ["ETB_Wattmeter", "ETB_Wattmeter"], 2, 0),
    # virtual / hardware: is_rx=False is the echo
    ("virtual", ["ETB_Wattmeter"], 2, 1),
    ("kvaser", ["ETB_Wattmeter"], 2, 1),
])
def test_what_counts_as_the_nodes_own_frame_depends_on_the_interface(interface, passed, echo,
                                                                     foreign):
    codec = DbcCodec()
    watt, est = codec["ETB_Wattmeter"].frame_id, codec["ECU_ThrottleEstimate"].frame_id
    frames = [can.Message(arbitration_id=i, data=bytes(8), is_extended_id=False, is_rx=rx)
              for i, rx in ((watt, True), (watt, False), (est, True), (est, False))]
    bus = LiveBus(_Frames(frames), sent_ids(codec, "VECU"), interface)
    got = [bus.recv(0.0) for _ in range(len(passed))]
    assert bus.recv(0.0) is None
    assert [codec.by_id[(m.arbitration_id, False)].name for m in got] == passed
    assert (bus.own_echo, bus.foreign_own_id) == (echo, foreign)


def test_inject_sends_one_fi_command_with_the_default_value():
    codec = DbcCodec()
    listener = can.Bus(interface="virtual", channel="live-inject")
    try:
        rc = cli_main(["inject", "--interface", "virtual", "--channel", "live-inject",
                       "--target", "tps", "--kind", "offset", "--quiet"])
        assert rc == 0
        msg = listener.recv(1.0)
        fi = codec["FI_Command"]
        assert msg is not None and msg.arbitration_id == fi.frame_id
        v = fi.decode(msg.data)
        assert v["FI_Target"] == 1 and v["FI_Kind"] == 4 and v["FI_Value"] == pytest.approx(0.5)
        assert listener.recv(0.1) is None
    finally:
        listener.shutdown()


@pytest.mark.parametrize("args,needle", [
    (["inject", "--target", "brakes", "--kind", "dead"], "unknown target 'brakes'"),
    (["inject", "--target", "tps", "--kind", "gain", "--value", "3"], "G must be in [0, 1]"),
    (["inject", "--target", "tps", "--kind", "dead", "--interface", "no-such-bus"], "no-such-bus"),
    (["ecu", "--interface", "no-such-bus"], "no-such-bus"),
    (["ecu", "--estimator", "bogus", "--duration", "1"], "bogus"),
    (["plant", "--log", "/nonexistent-dir/x.log"], "/nonexistent-dir/x.log"),
    (["plant", "--no-speed", "--extra-load", "1000"], "needs the speed part"),
])
def test_live_commands_reject_bad_input_with_one_line(args, needle, capsys):
    rc = cli_main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert needle in err and len(err.splitlines()) == 1, err


def test_sigterm_stops_the_plant_cleanly_with_log_and_summary_flushed(tmp_path):
    """One process on the in-process virtual bus: its recorder sees the plant's own frames."""
    log, summary, ready = tmp_path / "plant.blf", tmp_path / "plant.json", tmp_path / "ready"
    proc = subprocess.Popen(python_module("vecu", "plant", "--interface", "virtual", "--no-steering",
                                          "--log", str(log), "--summary", str(summary),
                                          "--ready-file", str(ready), "--quiet"),
                            stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: ready.exists() or proc.poll() is not None, 90.0)
        assert proc.poll() is None, proc.stderr.read()
        _wait_for(lambda: False, 0.5)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    s = json.loads(summary.read_text())
    assert s["stopped_by"] == "SIGTERM"
    sent = s["frames"]["plant_sent"]
    assert sent > 100 and s["ticks"]["plant"]["releases"] > 100
    with can.LogReader(str(log)) as reader:
        logged = list(reader)
    assert len(logged) == s["log"]["frames"] == sent  # every frame on disk after the signal


def _check_live_run(res: dict, kill: bool) -> None:
    assert res["returncodes"] == {"ecu": 0, "plant": 0, **({"inject": 0} if kill else {})}, res
    ecu = json.loads(Path(res["ecu_summary"]).read_text())
    plant = json.loads(Path(res["plant_summary"]).read_text())
    assert ecu["stopped_by"] == plant["stopped_by"] == "SIGTERM"
    th = ecu["throttle"]
    assert ecu["estimates"]["throttle"] > 500
    assert ecu["rx"]["accepted"] > 1000 and ecu["rx"]["rejected"] == 0  # own frames are no errors
    acc = th["estimate_vs_sensor_deg"]
    assert acc["n"] > 0 and acc["rms"] is not None and acc["rms"] == acc["rms"]  # finite
    if ecu["ticks"]["ecu"]["skipped"] == 0:
        # production estimator, alpha = 1: ~6 deg. A stall of the ECU process longer than the
        # 20-sample backlog drops wattmeter samples (see docs/live.md), so the bound is checked
        # only for runs without skipped ticks
        assert acc["std"] < 15.0, acc
    # the plant hears the ECU's broadcast: frames really crossed between the processes
    assert plant["bus"]["rx_by_id"].get("ECU_ThrottleEstimate", 0) > 500
    if res["interface"] == "udp_multicast":  # this interface echoes: both nodes saw their own
        assert ecu["bus"]["own_echo"] > 500 and plant["bus"]["own_echo"] > 500
    # every frame the ECU took from the bus is accounted for: read during the start-up phase
    # sync, or handed to the ECU's receive path
    taken = sum(ecu["bus"]["rx_by_id"].values())
    assert ecu["sync"]["discarded_frames"] > 0
    assert taken == ecu["sync"]["discarded_frames"] + ecu["rx"]["received"]
    with can.LogReader(res["ecu_log"]) as reader:  # written by the ECU, closed after SIGTERM
        ids = [m.arbitration_id for m in reader]
    est_id = DbcCodec()["ECU_ThrottleEstimate"].frame_id
    assert ids.count(est_id) >= 0.9 * ecu["estimates"]["throttle"]
    if kill:
        kills = [e for e in plant["fault_events"] if e["source"] == "can"]
        assert len(kills) == 1 and kills[0]["kind"] == "dead"
        kill_epoch = plant["start_epoch_s"] + kills[0]["t_s"]
        # a dead sensor (0 V) is out of range: found after the kill, and the ECU switched over.
        # Both times are release times of 1 ms ticks; a stalled process runs its release late, so
        # the comparison across processes allows 50 ms (stalls here reach ~10 ms)
        after = [c for c in th["status_changes"] if c[1] >= kill_epoch - 0.05]
        assert any(c[2] == "range_low" for c in after), th
        assert th["final_source"] == "estimate"


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_udp_multicast_plant_ecu_and_inject_in_separate_processes(tmp_path):
    # frames missing for 3 ms is a TPS timeout; this shared machine stalls processes for longer,
    # so the test loosens that one check (the dead sensor is caught by the range check)
    res = run_in_namespace(python_module(
        "vecu.live.scenario", str(tmp_path), "--plant-seconds", "2.5", "--inject-at", "0.3",
        "--ecu-arg=--tps-timeout-cycles=100"), timeout=240)
    assert res.returncode == 0, res.stderr + res.stdout
    _check_live_run(json.loads((tmp_path / "scenario.json").read_text()), kill=True)


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_udp_multicast_with_a_logger_on_the_bus_gives_no_false_tps_fault(tmp_path):
    """Issue 14 item 12: with python-can's logger as a third process on the bus of a 2-core
    machine, host stalls (the ECU's own, or the plant's) latched a false TPS timeout. No fault is
    injected: the TPS status must not leave ok while the plant runs (its silence after the plant
    stopped is a real one, reported after --host-gap-ms). The default 3-cycle timeout."""
    res = run_in_namespace(python_module(
        "vecu.live.scenario", str(tmp_path), "--plant-seconds", "12", "--logger", "--no-log"),
        timeout=300)
    assert res.returncode == 0, res.stderr + res.stdout
    sc = json.loads((tmp_path / "scenario.json").read_text())
    assert sc["returncodes"]["logger"] is not None and sc["logger_frames"] > 10_000, sc
    ecu = json.loads(Path(sc["ecu_summary"]).read_text())
    plant = json.loads(Path(sc["plant_summary"]).read_text())
    plant_stop_epoch = plant["start_epoch_s"] + plant["elapsed_s"]
    th = ecu["throttle"]
    early = [c for c in th["status_changes"] if c[1] < plant_stop_epoch]
    assert early == [], (early, th.get("host_gaps"), ecu["ticks"]["ecu"], plant["ticks"]["plant"])
    assert ecu["rx"]["rejected"] == 0 and ecu["estimates"]["throttle"] > 5_000


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
