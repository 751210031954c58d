"""Trace record and replay: a recorded run replays to the live ECU's own frames, bit for bit;
formats, ordering, truncation, scoring from truth frames, the CLI."""

from __future__ import annotations

import gzip
import json
import math
from collections import defaultdict

import can
import pytest

from vecu.cli import main as cli_main
from vecu.codec import DbcCodec
from vecu.replay.engine import ReplayConfig, replay
from vecu.replay.source import TraceSource
from vecu.runner import RunConfig, run

ECU_IDS = range(0x200, 0x400)


def ecu_frames(path: str) -> dict[int, list[tuple[float, bytes]]]:
    out: dict[int, list[tuple[float, bytes]]] = defaultdict(list)
    for m in can.LogReader(path):
        if m.arbitration_id in ECU_IDS and not m.is_error_frame:
            out[m.arbitration_id].append((round(m.timestamp, 6), bytes(m.data)))
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A 1.5 s run with every function, TPS dead at 0.7 s, recorded with truth frames."""
    d = tmp_path_factory.mktemp("rec")
    path = str(d / "drive.blf")
    result = run(RunConfig(duration_s=1.5, seed=3, kill_tps_at_s=0.7, log_path=path))
    return path, result.summary


def test_replay_reproduces_the_live_ecu_frame_for_frame(recorded, tmp_path):
    trace, _ = recorded
    out = str(tmp_path / "est.log")
    res = replay(ReplayConfig(trace=trace, out=out))
    assert res.error is None
    live, replayed = ecu_frames(trace), ecu_frames(out)
    for fid in (0x200, 0x210, 0x220, 0x230, 0x231, 0x300):
        n = len(live[fid])
        assert n > 0, hex(fid)
        assert replayed[fid][:n] == live[fid], f"0x{fid:X} differs from the live ECU"
    fr = res.summary["frames"]
    assert fr["read"] == sum(1 for _ in can.LogReader(trace))
    assert fr["rejected"] == 0 and fr["unknown_id"] == 0
    assert all(f["ran"] for f in res.summary["functions"].values())


def test_replay_is_bit_identical_across_runs(recorded, tmp_path):
    trace, _ = recorded
    outs = []
    for k in range(2):
        out = tmp_path / f"o{k}.log"
        replay(ReplayConfig(trace=trace, out=str(out), with_inputs=True))
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] and len(outs[0]) > 10_000


def test_score_from_frames_matches_the_live_probe(recorded):
    """Truth and estimates quantised by their DBC signals: the scores agree with the in-process
    probes (float truth) to within the quantisation."""
    trace, summary = recorded
    score = replay(ReplayConfig(trace=trace)).summary["score"]
    th = summary["throttle"]
    before, after = (th[p]["estimate_error_deg"] for p in ("before_kill", "after_kill"))
    rms = math.sqrt((before["n"] * before["rms"] ** 2 + after["n"] * after["rms"] ** 2)
                    / (before["n"] + after["n"]))
    assert score["throttle"]["estimate_error_deg"]["rms"] == pytest.approx(rms, abs=0.05)
    assert score["throttle"]["fallback_error_deg"]["n"] > 700  # estimate broadcast after the kill
    mf = summary["manifold"]["p_im_error_kpa"]["rms"]
    assert score["manifold"]["map_error_kpa"]["rms"] == pytest.approx(mf, abs=0.02)
    assert score["speed"]["speed_error_kmh"]["rms"] < 1.0
    assert score["steering"]["swa_estimate_error_deg"]["rms"] < 3.0


@pytest.mark.parametrize("suffix", [".log", ".asc", ".log.gz", ".trc", ".csv"])
def test_every_writable_format_replays_to_the_same_estimates(recorded, tmp_path, suffix):
    trace, _ = recorded
    copy = str(tmp_path / f"copy{suffix}")
    with can.Logger(copy) as writer:
        for msg in can.LogReader(trace):
            writer.on_message_received(msg)
    ref = tmp_path / "ref.log"
    replay(ReplayConfig(trace=trace, out=str(ref)))
    got = tmp_path / "got.log"
    res = replay(ReplayConfig(trace=copy, out=str(got)))
    assert res.error is None
    a, b = ecu_frames(str(ref)), ecu_frames(str(got))
    assert {k: [d for _, d in v] for k, v in a.items()} == {k: [d for _, d in v] for k, v in b.items()}


def test_mf4_round_trip_where_asammdf_is_installed(recorded, tmp_path):
    pytest.importorskip("asammdf")
    trace, _ = recorded
    copy = str(tmp_path / "copy.mf4")
    with can.Logger(copy) as writer:
        for msg in can.LogReader(trace):
            writer.on_message_received(msg)
    res = replay(ReplayConfig(trace=copy))
    assert res.error is None and res.summary["frames"]["rejected"] == 0


def _write_log(path, msgs):
    with can.Logger(str(path)) as w:
        for m in msgs:
            w.on_message_received(m)


def test_out_of_order_frames_are_reordered_and_counted(recorded, tmp_path):
    trace, _ = recorded
    msgs = list(can.LogReader(trace))[:3000]
    swapped = list(msgs)
    for i in range(10, len(swapped) - 1, 50):  # swap neighbours a few ms apart
        swapped[i], swapped[i + 5] = swapped[i + 5], swapped[i]
    _write_log(tmp_path / "sorted.log", msgs)
    _write_log(tmp_path / "swapped.log", swapped)
    a = replay(ReplayConfig(trace=str(tmp_path / "sorted.log"), out=str(tmp_path / "a.log")))
    b = replay(ReplayConfig(trace=str(tmp_path / "swapped.log"), out=str(tmp_path / "b.log")))
    assert b.summary["frames"]["out_of_order"] > 20 and b.summary["frames"]["late"] == 0
    assert a.summary["frames"]["out_of_order"] == 0
    assert (tmp_path / "a.log").read_bytes() == (tmp_path / "b.log").read_bytes()


def test_a_frame_older_than_the_window_is_delivered_late_not_lost(tmp_path):
    codec = DbcCodec()
    esc = codec["ESC_Motion"]
    msgs = [esc.frame({"ESC_WheelSpeed": 50.0, "ESC_LongAccel": 0.0}, k * 0.002) for k in range(200)]
    msgs.append(esc.frame({"ESC_WheelSpeed": 50.0, "ESC_LongAccel": 0.0}, 0.05))  # 350 ms late
    _write_log(tmp_path / "late.log", msgs)
    src = TraceSource(str(tmp_path / "late.log"))
    times = [t for t, _ in src]
    assert len(times) == 201 and times == sorted(times)
    assert src.stats.late == 1 and src.stats.out_of_order == 1


def test_truncated_files_give_one_line_naming_file_and_position_after_writing_output(
        recorded, tmp_path):
    trace, _ = recorded
    log = tmp_path / "full.log"
    _write_log(log, can.LogReader(trace))
    data = log.read_bytes()
    cut = tmp_path / "cut.log"
    cut.write_bytes(data[: len(data) // 2 + 7])  # mid-line
    out = tmp_path / "est.log"
    res = replay(ReplayConfig(trace=str(cut), out=str(out)))
    assert res.error is not None and str(cut) in res.error and "truncated" in res.error
    assert "\n" not in res.error and "after frame" in res.error
    assert len(ecu_frames(str(out))[0x200]) > 300  # everything before the cut was written
    blf = tmp_path / "cut.blf"
    raw = open(trace, "rb").read()
    blf.write_bytes(raw[: int(len(raw) * 0.6)])
    res = replay(ReplayConfig(trace=str(blf)))
    assert res.error is not None and str(blf) in res.error
    gz = tmp_path / "cut.log.gz"
    gz.write_bytes(gzip.compress(data)[: 5000])
    res = replay(ReplayConfig(trace=str(gz)))
    assert res.error is not None and str(gz) in res.error and res.summary["frames"]["read"] > 0


def test_cli_replay_writes_summary_plot_and_output(recorded, tmp_path, capsys):
    trace, _ = recorded
    summ, plot, out = tmp_path / "s.json", tmp_path / "p.png", tmp_path / "o.blf"
    rc = cli_main(["replay", trace, "--summary", str(summ), "--plot", str(plot), "--out", str(out),
                   "--no-progress"])
    assert rc == 0
    s = json.loads(summ.read_text())
    assert s["mode"] == "fast" and s["score"]["throttle"]["estimate_error_deg"]["n"] > 1000
    assert plot.stat().st_size > 20_000
    assert len(list(can.LogReader(str(out)))) == s["frames_written"] > 0
    assert "score throttle" in capsys.readouterr().out


@pytest.mark.parametrize("argv,needle", [
    (["replay", "missing.blf"], "missing.blf: no such file"),
    (["replay", "{trace}", "--format", "xyz"], "unknown format 'xyz'"),
    (["replay", "{trace}", "--speed", "0"], "--speed"),
    (["replay", "{trace}", "--map", "{bad_map}"], "bad.toml: [nonsense]: unknown function"),
    (["replay", "{trace}", "--dbc", "{bad_dbc}"], "bad.dbc:"),
])
def test_cli_replay_bad_input_is_one_line(recorded, tmp_path, capsys, argv, needle):
    trace, _ = recorded
    bad_map = tmp_path / "bad.toml"
    bad_map.write_text("[nonsense]\nx = 1\n")
    bad_dbc = tmp_path / "bad.dbc"
    bad_dbc.write_text("BO_ this is not a DBC\n")
    args = [a.format(trace=trace, bad_map=bad_map, bad_dbc=bad_dbc) for a in argv]
    rc = cli_main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and needle in err and len(err.splitlines()) == 1, err


def test_live_replay_sends_every_frame_and_reports_the_schedule_error(recorded, tmp_path):
    trace, _ = recorded
    short = tmp_path / "short.blf"
    _write_log(short, [m for m in can.LogReader(trace) if m.timestamp < 0.3])
    res = replay(ReplayConfig(trace=str(short), speed=1.0, channel="vecu-live-replay-test"))
    s = res.summary
    assert s["mode"] == "live" and res.error is None
    assert s["schedule_error"]["count"] == s["frames"]["read"] > 1000
    assert s["frames"]["ecu_rx"]["accepted"] > 500  # the ECU listened on the bus (drains all)
    assert s["functions"]["throttle"]["estimates_sent"] > 30  # fewer when a loaded machine skips ticks


def test_cantools_decodes_and_python_can_plays_our_log(recorded, tmp_path):
    import subprocess
    import sys
    trace, _ = recorded
    log = tmp_path / "short.log"
    _write_log(log, [m for m in can.LogReader(trace) if m.timestamp < 0.05])
    from vecu.codec import builtin_dbc_path
    out = subprocess.run([sys.executable, "-m", "cantools", "decode", str(builtin_dbc_path())],
                         input=log.read_text(), capture_output=True, text=True, check=True).stdout
    assert "ECU_ThrottleEstimate(" in out and "THR_AngleEst:" in out and "ETB_Wattmeter(" in out
    played = subprocess.run([sys.executable, "-m", "can.player", "-i", "virtual", "-c", "x",
                             "--ignore-timestamps", str(log)], capture_output=True, text=True,
                            timeout=60)
    assert played.returncode == 0, played.stderr



def test_run_log_carries_truth_frames_unless_told_not_to(tmp_path):
    truth_ids = {0x7A0, 0x7A1, 0x7A2, 0x7A3}
    for truth in (True, False):
        path = tmp_path / f"t{truth}.log"
        run(RunConfig(duration_s=0.1, kill_tps_at_s=None, log_path=str(path), truth=truth))
        ids = {m.arbitration_id for m in can.LogReader(str(path))}
        assert (truth_ids <= ids) is truth and bool(truth_ids & ids) is truth
        assert {0x100, 0x101, 0x120, 0x130, 0x131, 0x200} <= ids
