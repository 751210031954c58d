"""A toy fifth ECU function (tests/functions/toy: its folder, registered by this test only)
runs through `vecu run`, trace replay, a scenario, UDS, XCP and the summary, with no change
outside its folder: the harness iterates the registry (vecu.functions)."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from tests.functions import toy
from vecu import functions
from vecu.bus import SinkBus
from vecu.cli import main as cli_main
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.replay.engine import ReplayConfig, replay
from vecu.runner import run
from vecu.scenario.criteria import evaluate
from vecu.scenario.loader import load_scenario
from vecu.xcp.measurements import ecu_measurements

HERE = Path(__file__).parent


@pytest.fixture
def with_toy() -> Iterator[None]:
    with functions.registered(toy.SPEC):
        yield
    assert "toy" not in {s.name for s in functions.specs()}


def _frames(path: Path, frame_id: int) -> list[tuple[float, bytes]]:
    return [(round(m.timestamp, 6), bytes(m.data)) for m in can.LogReader(str(path))
            if m.arbitration_id == frame_id]


def test_register_refuses_a_taken_name_and_keeps_the_builtins():
    with pytest.raises(ValueError, match="registered already"):
        functions.register(functions.spec("steering"))
    with pytest.raises(ValueError, match="built-in"):
        functions.unregister("throttle")
    assert [s.name for s in functions.specs()][:5] == ["throttle", "speed", "steering", "manifold",
                                                     "fmu"]


def test_vecu_run_and_replay_carry_the_toy(with_toy, tmp_path, capsys):
    log, summary = tmp_path / "run.log", tmp_path / "run.json"
    assert cli_main(["run", "--duration", "1", "--seed", "4", "--log", str(log),
                     "--summary", str(summary)]) == 0
    out = capsys.readouterr().out
    s = json.loads(summary.read_text())
    toy_s = s["toy"]  # its typed summary, serialised with the rest
    assert toy_s["estimates_sent"] == 100  # one per 10 ms from the first sensor frame
    assert 0 < toy_s["level_error_v"]["rms"] < 0.2  # the low-pass tracks the 0.5 Hz level
    assert list(s)[-1] == "toy"  # after the built-in sections (report_rank)
    assert s["tasks"]["toy-probe"]["runs"] == 100
    assert "toy: level RMS error" in out
    estimates = _frames(log, 1409)
    assert len(estimates) == 100 and len(_frames(log, 1410)) == 100

    res = replay(ReplayConfig(trace=str(log), out=str(tmp_path / "out.log"), progress=False))
    rs = res.report
    assert rs.functions["toy"].ran and rs.functions["toy"].estimates_sent == 100
    assert rs.score is not None and rs.score.functions["toy"].errors["level_error_v"].n == 100
    # the ECU alone on the trace gives the toy's estimates of the run, bit for bit
    assert [d for _, d in _frames(tmp_path / "out.log", 1409)] == [d for _, d in estimates]


def test_without_the_toy_nothing_of_it_remains(tmp_path):
    s = run(RunConfig(duration_s=0.2, seed=4, kill_tps_at_s=None)).summary
    assert "toy" not in s and "toy-probe" not in s["tasks"]


def test_a_scenario_reads_the_toys_dids_over_uds(with_toy):
    scenario = load_scenario(HERE / "toy" / "drive.toml")
    result = run(scenario.config)
    verdicts = evaluate(scenario, result)
    assert verdicts and all(c.passed for c in verdicts), [c for c in verdicts if not c.passed]
    steps = result.report.uds_steps
    assert steps is not None and [st["passed"] for st in steps] == [True, True]
    raw = bytes.fromhex(steps[1]["response"])  # 62 05 00 + the level estimate, 0.001 V / bit
    assert raw[:3] == b"\x62\x05\x00"
    level = int.from_bytes(raw[3:5], "big") * 0.001
    assert 1.0 <= level <= 4.0  # 2.5 + sin(pi t): the estimate lies on the level's range
    assert result.report.functions["toy"].estimates_sent == 150


def test_the_xcp_slave_measures_the_toy(with_toy):
    codec = functions.function_codec()
    fns = [toy.SPEC.build(RunConfig(), codec, None)]
    node = EcuNode(SinkBus("toy"), codec, fns)
    names = [m.name for m in ecu_measurements(node)]
    assert names[0] == "toy.level_v"
    node.bus.shutdown()


def test_vecu_a2l_and_ecu_carry_the_toy(with_toy, tmp_path):
    """`vecu a2l` and `vecu ecu` build their codec from the registry, as run and replay do: the
    toy's own DBC reaches them (with vecu's codec alone, building the toy would fail)."""
    a2l = tmp_path / "toy.a2l"
    assert cli_main(["a2l", "--out", str(a2l)]) == 0
    assert '/begin MEASUREMENT toy.level_v' in a2l.read_text()
    # `vecu ecu` live on a virtual bus: a thread plays the toy's sensor, the toy's ECU side answers
    codec, seen, stop = functions.function_codec(), [], threading.Event()
    sensor = codec["TOY_Sensor"]

    def play() -> None:
        with can.Bus(interface="virtual", channel="toy-ecu") as bus:
            while not stop.wait(0.01):
                bus.send(sensor.frame({"TOY_Level": 3.0}, 0.0))
                while (msg := bus.recv(0)) is not None:
                    seen.append(msg.arbitration_id)

    player = threading.Thread(target=play)
    player.start()
    try:
        assert cli_main(["ecu", "--interface", "virtual", "--channel", "toy-ecu", "--duration",
                         "0.5", "--sync-timeout", "0", "--quiet"]) == 0
    finally:
        stop.set()
        player.join()
    assert seen.count(1409) > 10  # TOY_Estimate every 10 ms once the sensor came
