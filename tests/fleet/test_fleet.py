"""Fleet replay on real Dask: a fleet recorded by `vecu run` under two calibrations, replayed on a
LocalCluster of 2 workers and on real `dask scheduler` / `dask worker` processes; each trace's
result is that of `vecu replay` alone; the diff finds exactly the signals the calibration changed
(oracle: the two recordings decoded with cantools); resume adds nothing twice; bad traces are
their own error rows."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import cantools
import pytest

from vecu.codec import builtin_dbc_path
from vecu.config import RunConfig
from vecu.fleet.diff import DiffSpec, load_diff_spec
from vecu.fleet.engine import RUNS_CSV, run_fleet
from vecu.fleet.task import COLUMNS, FleetConfig, outputs
from vecu.replay.engine import ReplayConfig, replay
from vecu.runner import run

pytest.importorskip("distributed")

CALIBRATION = ("ecu.speed.filter.q_jerk", 40.0)  # the speed filter's process noise only
DURATION_S = 2.0
TIMING = ("wall_time_s", "x_realtime", "frames_per_s", "kernel_load_s", "kernels")


def _record(path: Path, sets: tuple = ()) -> Path:
    cfg = RunConfig(duration_s=DURATION_S, seed=5, kill_tps_at_s=1.2, log_path=str(path))
    run(cfg.with_params(sets) if sets else cfg)
    return path


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> list[Path]:
    """Two drives, the same seed, the second with the ECU's speed filter recalibrated."""
    d = tmp_path_factory.mktemp("drives")
    return [_record(d / "base.log"), _record(d / "recal.log", (CALIBRATION,))]


@pytest.fixture(scope="module")
def diffed(drives, tmp_path_factory):
    """The fleet on a LocalCluster of 2 workers: zero tolerance, output traces as .log."""
    out = tmp_path_factory.mktemp("fleet")
    spec = DiffSpec(lsb=0.0)
    fleet = FleetConfig(ReplayConfig(trace=""), "log", spec)
    res = run_fleet([str(p) for p in drives], fleet, out, workers=2, junit=str(out / "r.xml"))
    return fleet, out, res


def _rows(out: Path) -> list[dict[str, str]]:
    import csv

    with open(out / RUNS_CSV) as fh:
        return list(csv.DictReader(fh))


def test_one_trace_of_the_fleet_is_vecu_replay_of_it_alone(drives, diffed, tmp_path):
    _, out, res = diffed
    assert res.done == 2 and res.new == 2 and res.errors == 0
    alone = tmp_path / "alone.log"
    single = replay(ReplayConfig(trace=str(drives[1]), out=str(alone), progress=False))
    paths = outputs(out, "recal.log", "log")
    assert paths["out"].read_bytes() == alone.read_bytes()
    fleet_summary = json.loads(paths["summary"].read_text())
    mine = dict(single.summary)
    for key in TIMING:
        fleet_summary.pop(key), mine.pop(key)
    fleet_summary["config"].pop("out"), mine["config"].pop("out")
    assert fleet_summary == json.loads(json.dumps(mine))


def _oracle(a: Path, b: Path) -> set[str]:
    """Signals of the ECU's messages whose recorded values differ between the two traces
    (frame by frame, cantools' decoding; E2E CRC / counter left out: protocol, not values)."""
    db = cantools.database.load_file(str(builtin_dbc_path()))
    ecu = {m.frame_id: m for m in db.messages if "VECU" in m.senders}

    def frames(path: Path) -> list[tuple[int, dict]]:
        return [(m.arbitration_id, ecu[m.arbitration_id].decode(m.data, decode_choices=False))
                for m in can.LogReader(str(path)) if m.arbitration_id in ecu]

    fa, fb = frames(a), frames(b)
    assert [i for i, _ in fa] == [i for i, _ in fb]  # same seed: the same frames, in order
    changed = set()
    for (fid, va), (_, vb) in zip(fa, fb):
        for name, x in va.items():
            if name.endswith(("_CRC", "_AliveCounter")):
                continue
            if not (x == vb[name] or (math.isnan(x) and math.isnan(vb[name]))):
                changed.add(f"{ecu[fid].name}.{name}")
    return changed


def test_the_diff_finds_exactly_the_signals_the_calibration_changed(drives, diffed):
    _, out, _ = diffed
    rows = {r["name"]: r for r in _rows(out)}
    base, recal = rows["base.log"], rows["recal.log"]
    # the base drive replays to what it recorded: nothing differs, nothing unpaired
    assert (base["status"], base["verdict"], base["diff"]) == ("ok", "pass", "pass")
    assert base["diff_failed_signals"] == "" and int(base["diff_paired"]) > 3000
    assert base["diff_recorded_only"] == base["diff_replayed_only"] == "0"
    # the recalibrated drive replayed with the base calibration: exactly the changed signals
    expected = _oracle(drives[0], drives[1])
    assert expected and all(s.startswith("ECU_SpeedEstimate.") for s in expected)
    assert recal["status"] == "fail" and recal["verdict"] == "fail"
    assert set(recal["diff_failed_signals"].split()) == expected
    detail = json.loads(outputs(out, "recal.log", None)["diff"].read_text())
    assert {k for k, s in detail["signals"].items() if s["outside"]} == expected
    assert all(e["passed"] and e["recorded_crc_errors"] == 0 for e in detail["e2e"].values())
    first = min(detail["signals"][s]["first_divergence_s"] for s in expected)
    assert first == float(recal["diff_first_divergence_s"]) and 0 <= first < DURATION_S


@pytest.mark.slow
def test_the_diff_with_default_tolerances_replayed_under_the_new_calibration(drives, tmp_path):
    """The recalibrated drive replayed with its own calibration: it passes; the base drive then
    fails on signals of the speed function only."""
    fleet = FleetConfig(ReplayConfig(trace="", sets=(CALIBRATION,)), None, load_diff_spec(None))
    res = run_fleet([str(p) for p in drives], fleet, tmp_path / "o", workers=1)
    rows = {r["name"]: r for r in res.summary["rows"]}
    assert rows["recal.log"]["verdict"] == "pass"
    failed = rows["base.log"]["diff_failed_signals"].split()
    assert failed and all(s.startswith("ECU_SpeedEstimate.") for s in failed)


def test_report_summary_and_junit_have_a_row_per_trace(diffed):
    _, out, res = diffed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["traces"] == 2 and summary["ok"] == 1 and summary["fail"] == 1
    assert summary == res.summary
    html = (out / "report.html").read_text()
    assert html.count("<tr><td><a href=") == 2 and "fleet.png" in html
    assert (out / "fleet.png").stat().st_size > 1000
    suite = ET.parse(out / "r.xml").getroot().find("testsuite")
    cases = {c.get("name"): c for c in suite.iter("testcase")}
    assert set(cases) == {"base.log", "recal.log"}
    assert cases["base.log"].find("failure") is None
    assert "SPD_" in cases["recal.log"].find("failure").text


def test_resume_completes_a_cut_table_without_replaying_anything_twice(drives, diffed, tmp_path):
    fleet, out, _ = diffed
    cut = tmp_path / "cut"
    cut.mkdir()
    shutil.copy(out / "meta.json", cut / "meta.json")
    lines = (out / RUNS_CSV).read_text().splitlines(keepends=True)
    (cut / RUNS_CSV).write_text(lines[0] + lines[2] + lines[1][:15])  # recal done, base cut
    res = run_fleet([str(p) for p in drives], fleet, cut, workers=1, resume=True)
    assert res.new == 1 and res.done == 2
    assert (cut / RUNS_CSV).read_bytes() == (out / RUNS_CSV).read_bytes()
    again = run_fleet([str(p) for p in drives], fleet, cut, workers=1, resume=True)
    assert again.new == 0 and (cut / RUNS_CSV).read_bytes() == (out / RUNS_CSV).read_bytes()


@pytest.mark.slow
def test_a_real_dask_scheduler_and_worker_give_the_same_table(drives, diffed, tmp_path,
                                                                 dask_scheduler):
    fleet, out, _ = diffed
    remote = tmp_path / "remote"
    run_fleet([str(p) for p in drives], fleet, remote, scheduler=dask_scheduler)
    assert (remote / RUNS_CSV).read_bytes() == (out / RUNS_CSV).read_bytes()
    assert (outputs(remote, "base.log", "log")["out"].read_bytes()
            == outputs(out, "base.log", "log")["out"].read_bytes())


@pytest.mark.slow
def test_bad_traces_are_their_own_error_rows_and_the_rest_go_on(drives, tmp_path):
    d = tmp_path / "mixed"
    d.mkdir()
    good = shutil.copy(drives[0], d / "a_good.log")
    text = drives[0].read_bytes()
    (d / "b_cut.log").write_bytes(text[: len(text) // 2])  # cut mid-line by a kill
    (d / "c_garbage.blf").write_bytes(b"this is no BLF file" * 10)
    junit = tmp_path / "r.xml"
    res = run_fleet([str(good), str(d / "b_cut.log"), str(d / "c_garbage.blf")],
                    FleetConfig(ReplayConfig(trace=""), None, DiffSpec()), tmp_path / "o",
                    workers=2, junit=str(junit))
    rows = {r["name"]: r for r in res.summary["rows"]}
    assert res.done == 3 and res.errors == 2 and rows["a_good.log"]["status"] == "ok"
    cut = rows["b_cut.log"]
    assert cut["status"] == "error" and "b_cut.log" in cut["error"] and "frame" in cut["error"]
    assert int(cut["frames_read"]) > 0  # what was read before the cut is in its summary
    assert rows["c_garbage.blf"]["status"] == "error" and "c_garbage.blf" in rows[
        "c_garbage.blf"]["error"]
    cases = {c.get("name"): c for c in ET.parse(junit).getroot().iter("testcase")}
    assert cases["b_cut.log"].find("error").get("message") == cut["error"]
    assert cases["a_good.log"].find("error") is None


def _die_once(marker: str) -> dict:
    """A task whose first attempt kills its worker process (as the OOM killer would)."""
    import os

    if not Path(marker).exists():
        Path(marker).write_text("died")
        os._exit(1)
    return {"trace": marker, "status": "ok"}


@pytest.mark.slow
def test_a_worker_killed_mid_trace_is_retried_once(tmp_path):
    from vecu.campaign.cluster import run_rows

    got: list[dict] = []
    marker = tmp_path / "attempt"
    stopped = run_rows(_die_once, [(str(marker),)], ["die-once"], got.append,
                       lambda item, exc: {"status": "error", "error": str(exc)}, workers=1,
                       retries=1)
    assert stopped is None and got == [{"trace": str(marker), "status": "ok"}]
    assert marker.read_text() == "died"


@pytest.mark.slow
def test_killed_vecu_replay_resumes_to_the_same_table(drives, diffed, tmp_path):
    """`vecu replay DIR --diff` killed with its cluster after the first row: --resume ends with
    the same runs.csv as the uninterrupted fleet."""
    _, out, _ = diffed
    fleet_dir = tmp_path / "f"
    spec = tmp_path / "zero.toml"
    spec.write_text("lsb = 0\n")
    argv = [sys.executable, "-m", "vecu", "replay", str(drives[0].parent), "--diff", str(spec),
            "--out-dir", str(fleet_dir), "--out-format", "log", "--workers", "1",
            "--no-progress"]
    import os

    env = {**os.environ, "VECU_KERNELS": "python",
           "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=env)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            csv_path = fleet_dir / RUNS_CSV
            if csv_path.exists() and len(csv_path.read_text().splitlines()) >= 2:
                break
            time.sleep(0.05)
    finally:
        import signal

        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    done = subprocess.run([*argv, "--resume"], env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    assert done.returncode == 1, done.stderr  # the recalibrated drive fails its diff
    assert "2/2 traces" in done.stdout
    assert (fleet_dir / RUNS_CSV).read_bytes() == (out / RUNS_CSV).read_bytes()
    header = (fleet_dir / RUNS_CSV).read_text().splitlines()[0]
    assert header.split(",") == COLUMNS
