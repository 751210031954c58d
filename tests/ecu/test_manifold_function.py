"""ECU manifold function: implausible engine events (in the DBC range, impossible for the
filter) are refused, counted and logged once per burst; they never raise out of the tick nor
reach the filter or the CAC prediction (issue 14, items 1-2)."""

from __future__ import annotations

import logging
import math

import can
import pytest

from vecu.bus import open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.ecu.manifold_function import ManifoldFunction
from vecu.ecu.node import EcuNode

CODEC = DbcCodec()
EVENT, INTAKE, OUT = CODEC["ENG_Event"], CODEC["ENG_Intake"], CODEC["ECU_ManifoldEstimate"]


@pytest.fixture
def rig(request):
    channel = f"ecu-manifold-{request.node.name}"
    ecu_bus, tester = open_bus(channel=channel), open_bus(channel=channel)
    fn = ManifoldFunction(CODEC)
    yield EcuNode(ecu_bus, CODEC, [fn]), fn, tester
    ecu_bus.shutdown()
    tester.shutdown()


def event(counter: int, rpm: float = 1500.0, map_kpa: float = 40.0, angle: float = 10.0
          ) -> can.Message:
    data = EVENT.encode({"ENG_EventCounter": counter, "ENG_Speed": rpm,
                         "ENG_ThrottleSetpoint": angle, "ENG_ThrottleAngle": angle,
                         "ENG_MAP": map_kpa})
    return can.Message(arbitration_id=EVENT.frame_id, is_extended_id=False, data=data)


def intake(counter: int, iat_c: float = 30.0) -> can.Message:
    return can.Message(arbitration_id=INTAKE.frame_id, is_extended_id=False,
                       data=INTAKE.encode({"ENG_IntakeCounter": counter, "ENG_IAT": iat_c}))


def run_frames(ecu: EcuNode, tester, frames: list[can.Message]) -> list[dict[str, float]]:
    """Each frame, then one 1 ms ECU tick; the manifold estimates the tester received."""
    for k, msg in enumerate(frames):
        tester.send(msg)
        ecu.tick(k * NS_PER_MS)
    out = []
    while (m := tester.recv(0.0)) is not None:
        if m.arbitration_id == OUT.frame_id:
            out.append(OUT.decode(m.data))
    return out


@pytest.mark.parametrize("payload", ["0000000000000000", "0001000000204E00"])
def test_issue_repro_frames_are_refused_not_raised(rig, payload):
    """`110#0000000000000000` (0 rpm) and `110#0001000000204E00` (0.25 rpm) from the issue."""
    ecu, fn, tester = rig
    frame = can.Message(arbitration_id=0x110, is_extended_id=False, data=bytes.fromhex(payload))
    assert run_frames(ecu, tester, [frame]) == []
    assert fn.implausible_inputs == 1 and fn.events == 0
    assert ecu.rx.implausible == 1 and ecu.rx.value_errors == 1 and ecu.rx.accepted == 0
    assert ecu.rx.accepted + ecu.rx.ignored + ecu.rx.rejected == ecu.rx.received


@pytest.mark.parametrize("rpm,map_kpa", [(0.0, 40.0), (0.25, 200.0), (0.25, 0.0), (299.75, 200.0)])
def test_implausible_speed_never_reaches_the_filter_or_the_prediction(rig, rpm, map_kpa):
    ecu, fn, tester = rig
    frames = [event(0), intake(0), event(1, rpm, map_kpa), intake(1), event(2), intake(2)]
    estimates = run_frames(ecu, tester, frames)
    assert fn.implausible_inputs == 1 and fn.events == 2 and len(estimates) == 2
    assert fn.filter.bad_inputs == 0 and fn.filter.resets == 0 and fn.estimator_faults == 0
    assert all(math.isfinite(v) for e in estimates for v in e.values())
    assert fn.lost_events == 1  # the refused event is a counter gap, like a lost frame


def test_a_refused_event_leaves_the_filter_as_if_it_never_came(request):
    good = [event(0), intake(0), event(2, 2500.0, 60.0, 20.0), intake(2)]
    with_bad = good[:2] + [event(1, 0.0, 200.0), intake(1)] + good[2:]
    results = []
    for name, frames in (("clean", good), ("bad", with_bad)):
        channel = f"ecu-manifold-same-{name}"
        ecu_bus, tester = open_bus(channel=channel), open_bus(channel=channel)
        try:
            results.append(run_frames(EcuNode(ecu_bus, CODEC, [ManifoldFunction(CODEC)]),
                                      tester, frames))
        finally:
            ecu_bus.shutdown()
            tester.shutdown()
    assert results[0] == results[1] and len(results[0]) == 2


def test_refusals_are_logged_once_per_burst(rig, caplog):
    ecu, fn, tester = rig
    frames = ([event(0)] + [event(k, 0.0) for k in range(1, 6)] + [event(6)]
              + [event(7, 100.0), event(8, 0.25), event(9, 299.0), event(10)])
    with caplog.at_level(logging.INFO, logger="vecu.ecu.manifold_function"):
        run_frames(ecu, tester, frames)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert fn.implausible_inputs == 8 and ecu.rx.implausible == 8
    assert len(warnings) == 2 and "engine speed 0 rpm outside 300..9000 rpm" in warnings[0].getMessage()
    assert sum("events again after" in r.getMessage() for r in caplog.records) == 2
