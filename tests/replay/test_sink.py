"""The ECU's estimate sinks (vecu.bus.EstimateSink): every frame the ECU sends reaches them with the
values it carries, equal to cantools' decode of that frame, and the replay's truth scorer
scores those values without decoding a single frame the ECU sent."""

from __future__ import annotations

import math
from pathlib import Path

import can
import cantools

from vecu.assembly import TICK_NS, build_functions
from vecu.bus import SinkBus
from vecu.clock import NS_PER_S
from vecu.codec import TRUTH_DBC, DbcCodec, Values, builtin_dbc_path
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.replay.scoring import TruthScorer
from vecu.replay.source import TraceSource

TRACE = Path(__file__).resolve().parents[2] / "traces" / "drive_tps_dead.blf"
SECONDS = 1.0


class Recorder:
    """An estimate sink that keeps what it is handed."""

    def __init__(self) -> None:
        self.frames: list[tuple[Values | None, can.Message, int]] = []

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        self.frames.append((values, can.Message(  # a copy: a later sink may retime msg
            arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
            data=bytes(msg.data)), t_ns))


def _replay_head(sinks: list, scorer: TruthScorer) -> None:
    """The ECU over the trace's first SECONDS: its inputs received, truth frames to the
    scorer, a tick every ms (as vecu.replay's warm-up feeds it)."""
    codec = DbcCodec()
    ecu = EcuNode(SinkBus("sink-test"), codec, build_functions(RunConfig(), codec).enabled(),
                  arm_on_input=True, sinks=sinks)
    next_tick = 0
    for t_ns, msg in TraceSource(str(TRACE)):
        if t_ns > SECONDS * NS_PER_S:
            break
        while next_tick < t_ns:
            ecu.tick(next_tick)
            next_tick += TICK_NS
        key = (msg.arbitration_id, msg.is_extended_id)
        if key in scorer.truth_ids:
            scorer.on_truth(msg, t_ns)
        elif key in ecu.consumed_ids:
            ecu.receive(msg, t_ns)
    ecu.bus.shutdown()


def test_the_sink_values_are_cantools_decode_of_the_frame_sent():
    recorder = Recorder()
    _replay_head([recorder], TruthScorer(DbcCodec()))
    db = cantools.database.Database()
    for path in (builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)):
        db.add_dbc_file(str(path))
    with_values = 0
    names_without = set()
    for values, msg, t_ns in recorder.frames:
        message = db.get_message_by_frame_id(msg.arbitration_id)
        if values is None:
            names_without.add(message.name)
            continue
        decoded = message.decode(msg.data, decode_choices=False)
        want = [decoded[s.name] for s in message.signals]
        assert len(values) == len(want) and all(
            v == w or (math.isnan(v) and math.isnan(w)) for v, w in zip(values, want)), (
            message.name, values, want)
        assert t_ns % TICK_NS == 0
        with_values += 1
    assert with_values > 1500  # throttle every ms, speed, steering, manifold
    assert names_without == {"ECU_Status", "ECU_Diag"}  # not made from values


def test_the_scorer_decodes_no_frame_the_ecu_sent(monkeypatch):
    codec = DbcCodec()  # the scorer's own: its decoders are counted
    decodes = {"n": 0}
    for name in ("ECU_ThrottleEstimate", "ECU_SpeedEstimate", "ECU_SteeringEstimate",
                 "ECU_ManifoldEstimate", "ECU_ManifoldSigma"):
        fc = codec[name]
        for method in ("decode", "decode_exact", "decode_checked", "decode_cantools"):
            def counted(*args, _real=getattr(fc, method)):
                decodes["n"] += 1
                return _real(*args)
            monkeypatch.setattr(fc, method, counted)
    scorer = TruthScorer(codec)
    _replay_head([scorer], scorer)
    score = scorer.summary()
    assert decodes["n"] == 0
    throttle = score.functions["throttle"].errors["broadcast_error_deg"]
    assert score.truth_frames > 1000 and throttle.n > 500
    assert math.isfinite(throttle.rms) and throttle.rms < 5.0
