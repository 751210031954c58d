"""Every fault kind of vecu.faults has the effect it promises, seen on the bus from a plant node."""

from __future__ import annotations

import numpy as np
import pytest

from vecu.clock import NS_PER_MS
from vecu.e2e import AliveCounterCheck
from vecu.faults import FaultInjector, FaultKind, make_fault, parse_site


@pytest.fixture
def rig(plant_rig):
    return plant_rig("faults-test", with_speed=True)


def run_ticks(node, tester, first_ms, n):
    """Tick the plant n times from first_ms; return every frame it put on the bus."""
    for k in range(first_ms, first_ms + n):
        node.tick(k * NS_PER_MS)
    out = []
    while (m := tester.recv(0.0)) is not None:
        out.append(m)
    return out


def of(codec, frames, name):
    fc = codec[name]
    return [m for m in frames if m.arbitration_id == fc.frame_id and not m.is_error_frame]


@pytest.mark.parametrize("kind,value,check", [
    (FaultKind.DRIFT, 2.0, lambda f: [f.apply(1.0, t) for t in (0, 500_000_000)] == [1.0, 2.0]),
    (FaultKind.QUANTISE, 0.5, lambda f: [f.apply(v) for v in (1.2, 1.3, -0.2)] == [1.0, 1.5, 0.0]),
    (FaultKind.GAIN, 0.0, lambda f: f.apply(3.3) == 0.0),
])
def test_new_signal_faults_transform_values(kind, value, check):
    assert check(make_fault(kind, value, np.random.default_rng(0)))


def test_signal_fault_on_any_dbc_signal_is_re_encoded(rig):
    codec, node, tester, inj = rig
    healthy = of(codec, run_ticks(node, tester, 0, 20), "ESC_Motion")
    assert min(codec["ESC_Motion"].decode(m.data)["ESC_WheelSpeed"] for m in healthy) > 70
    inj.inject(20 * NS_PER_MS, "wheel", FaultKind.DEAD)
    inj.inject(20 * NS_PER_MS, "accel", FaultKind.OFFSET, 3.0)
    faulty = of(codec, run_ticks(node, tester, 20, 20), "ESC_Motion")
    values = [codec["ESC_Motion"].decode(m.data) for m in faulty]
    assert len(values) == 10 and all(v["ESC_WheelSpeed"] == 0.0 for v in values)
    assert np.mean([v["ESC_LongAccel"] for v in values]) > 2.0  # cruise: ~0 + 3 offset
    inj.clear(40 * NS_PER_MS, "wheel")
    again = of(codec, run_ticks(node, tester, 40, 4), "ESC_Motion")
    assert all(codec["ESC_Motion"].decode(m.data)["ESC_WheelSpeed"] > 70 for m in again)
    assert inj.frame_stage_active  # the accel offset is still on


def test_tps_signal_fault_keeps_a_valid_crc_and_the_fast_path_when_idle(rig):
    codec, node, tester, inj = rig
    assert not inj.frame_stage_active
    inj.inject(0, "TPS_Sensor.TPS_Voltage", FaultKind.SHORT_SUPPLY)
    assert not inj.frame_stage_active  # the TPS part applies its own signal faults
    frames = of(codec, run_ticks(node, tester, 0, 5), "TPS_Sensor")
    assert all(codec["TPS_Sensor"].crc_ok(m.data) for m in frames)
    assert {codec["TPS_Sensor"].decode(m.data)["TPS_Voltage"] for m in frames} == {5.0}


def test_frames_stop_and_dropout_on_any_message(rig):
    codec, node, tester, inj = rig
    inj.inject(0, "ESC_Motion", FaultKind.FRAMES_STOP)
    assert of(codec, run_ticks(node, tester, 0, 10), "ESC_Motion") == []
    inj.inject(10 * NS_PER_MS, "ESC_Motion", FaultKind.DROPOUT, 0.5)
    n = len(of(codec, run_ticks(node, tester, 10, 400), "ESC_Motion"))
    assert 60 < n < 140  # 200 frames, half lost (seeded)


def test_delay_shifts_frames_by_the_delay(rig):
    codec, node, tester, inj = rig
    inj.inject(0, "TPS_Sensor", FaultKind.DELAY, 5.0)
    frames = of(codec, run_ticks(node, tester, 0, 12), "TPS_Sensor")
    assert len(frames) == 7  # frames of 0..6 ms released at 5..11 ms
    assert frames[0].timestamp == pytest.approx(0.005)
    inj.clear(12 * NS_PER_MS, "TPS_Sensor", FaultKind.DELAY)
    later = of(codec, run_ticks(node, tester, 12, 10), "TPS_Sensor")
    assert len(later) == 15  # the 5 held frames still go out, then the live ones
    assert not inj.frame_stage_active


def test_e2e_faults_fail_exactly_the_intended_check(rig):
    codec, node, tester, inj = rig
    tps = codec["TPS_Sensor"]
    inj.inject(0, "tps", FaultKind.BAD_CRC)
    frames = of(codec, run_ticks(node, tester, 0, 5), "TPS_Sensor")
    assert len(frames) == 5 and not any(tps.crc_ok(m.data) for m in frames)
    inj.inject(5 * NS_PER_MS, "tps", FaultKind.WRONG_COUNTER)
    frames = of(codec, run_ticks(node, tester, 5, 5), "TPS_Sensor")
    assert all(tps.crc_ok(m.data) for m in frames)
    counters = [tps.decode(m.data)["TPS_AliveCounter"] for m in frames]
    check = AliveCounterCheck()
    assert len(set(counters)) == 1 and [check.check(c) for c in counters][1:] == [False] * 4
    with pytest.raises(ValueError, match="no E2E"):
        inj.inject(10 * NS_PER_MS, "ESC_Motion", FaultKind.BAD_CRC)


def test_burst_babble_and_error_frames(rig):
    codec, node, tester, inj = rig
    inj.inject(0, "TPS_Sensor", FaultKind.BURST, 3)
    assert len(of(codec, run_ticks(node, tester, 0, 4), "TPS_Sensor")) == 12
    inj.inject(4 * NS_PER_MS, "TPS_Sensor", FaultKind.BABBLE, 5)
    frames = of(codec, run_ticks(node, tester, 4, 10), "TPS_Sensor")
    bad = [m for m in frames if not codec["TPS_Sensor"].crc_ok(m.data)]
    assert len(frames) == 60 and len(bad) >= 48  # 10 real + 50 garbage (1/256 pass the CRC)
    inj.inject(14 * NS_PER_MS, "ESC_Motion", FaultKind.ERROR_FRAMES, 0.5)
    errors = [m for m in run_ticks(node, tester, 14, 10) if m.is_error_frame]
    assert len(errors) == 5


def test_each_change_is_announced_as_an_fi_event_frame(rig):
    codec, node, tester, inj = rig
    inj.inject(2 * NS_PER_MS, "wheel", FaultKind.OFFSET, 7.5, source="scenario")
    start = of(codec, run_ticks(node, tester, 2, 1), "FI_Event")
    inj.clear(3 * NS_PER_MS, "wheel")
    end = of(codec, run_ticks(node, tester, 3, 1), "FI_Event")
    assert len(start) == len(end) == 1
    ev0, ev1 = (codec["FI_Event"].decode(f[0].data) for f in (start, end))
    assert ev0["FI_EvActive"] == 1 and ev0["FI_EvValue"] == 7.5 and ev0["FI_EvSource"] == 1
    assert ev1["FI_EvActive"] == 0 and ev1["FI_EvKind"] == int(FaultKind.OFFSET)
    assert ev1["FI_EvMessageId"] == codec["ESC_Motion"].frame_id and ev1["FI_EvSignal"] == 1
    assert end[0].timestamp == pytest.approx(0.003)


def test_bad_targets_and_values_are_clear_errors():
    inj = FaultInjector(np.random.default_rng(0))
    for target, kind, value, needle in (
            ("NoSuchMsg", FaultKind.FRAMES_STOP, None, "no message"),
            ("ESC_Motion.Nope", FaultKind.DEAD, None, "has no signal"),
            ("ESC_Motion", FaultKind.DEAD, None, "needs MESSAGE.SIGNAL"),
            ("tps", FaultKind.DROPOUT, 1.5, "must be in [0, 1]"),
            ("a.b.c", FaultKind.DEAD, None, "bad fault target")):
        with pytest.raises(ValueError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            inj.inject(0, target, kind, value)
    assert parse_site("swa").name == "swa" and parse_site("ESC_Motion").name == "ESC_Motion"


def plant_messages(codec):
    return [codec[n] for n in ("TPS_Sensor", "ETB_Wattmeter", "ENG_Event", "ENG_Intake",
                               "ESC_Motion", "CHS_Lateral", "SWA_Sensor")]


def middle_frame(fc, counter=0):
    values = {s.name: (s.minimum + s.maximum) / 2 for s in fc.signals}
    for s in fc.signals:
        if s.name.endswith("Counter"):
            values[s.name] = counter % (s.maximum + 1)
    return fc.frame(values, 0.0)


@pytest.mark.parametrize("kind,value,expect", [
    (FaultKind.OFFSET, 300.0, lambda k: (k + 300) % 256),
    (FaultKind.OFFSET, -1e4, lambda k: (k - 10_000) % 256),
    (FaultKind.GAIN, 1.0, lambda k: k),
    (FaultKind.NOISE, 1e4, None),
    (FaultKind.DRIFT, 1e6, None),
    (FaultKind.SHORT_SUPPLY, None, lambda k: 255),
])
def test_value_faults_on_counters_wrap_modulo_their_range(kind, value, expect):
    """Issue 14 item 3: an offset or noise fault on ENG_EventCounter overflowed the re-encode."""
    from vecu.codec import DbcCodec

    codec = DbcCodec()
    inj = FaultInjector(np.random.default_rng(0), codec)
    for target in ("ENG_Event.ENG_EventCounter", "ENG_Intake.ENG_IntakeCounter"):
        inj.inject(0, target, kind, value)
    for name in ("ENG_Event", "ENG_Intake"):
        fc = codec[name]
        counter = fc.signals[0].name
        for k in range(0, 600, 7):
            inj.now_ns = k * NS_PER_MS
            (out,) = inj.process(middle_frame(fc, k))
            got = fc.decode(out.data)[counter]
            assert 0 <= got <= 255 and got == int(got)
            if expect is not None:
                assert got == expect(k % 256)


@pytest.mark.parametrize("kind,value", [
    (FaultKind.OFFSET, 1e300), (FaultKind.OFFSET, -1e300), (FaultKind.NOISE, 1e300),
    (FaultKind.DRIFT, 1e300), (FaultKind.DRIFT, -1e300), (FaultKind.QUANTISE, 1e-300),
    (FaultKind.QUANTISE, 1e300), (FaultKind.SHORT_SUPPLY, None), (FaultKind.GAIN, 0.0),
])
def test_any_fault_value_on_any_signal_is_encoded_saturated_or_wrapped(kind, value):
    from vecu.codec import DbcCodec

    codec = DbcCodec()
    for fc in plant_messages(codec):
        for sig in fc.signals:
            inj = FaultInjector(np.random.default_rng(1), codec)
            inj.inject(0, f"{fc.name}.{sig.name}", kind, value)
            for k in range(3):
                inj.now_ns = (1 + k) * 1_000_000_000
                out = inj.process(middle_frame(fc, k))
                for msg in out:
                    got = fc.decode(msg.data)[sig.name]
                    assert sig.minimum <= got <= sig.maximum, (fc.name, sig.name, got)
                    # P11's check also refuses a counter of 15 (its counters run 0..14)
                    assert fc.crc_ok(msg.data) or (
                        sig.name == fc.e2e.counter_signal
                        and got >= fc.e2e.protection.counter_modulo)


@pytest.mark.parametrize("value", [1e-300, 5e-324])
def test_quantise_with_a_tiny_step_passes_the_value_through(value):
    f = make_fault(FaultKind.QUANTISE, value, np.random.default_rng(0))
    assert f.apply(2.5) == 2.5 and f.apply(-1e300) == -1e300


@pytest.mark.parametrize("kind", [FaultKind.OFFSET, FaultKind.NOISE, FaultKind.DRIFT,
                                  FaultKind.QUANTISE, FaultKind.GAIN])
@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_non_finite_fault_values_are_refused(kind, value):
    with pytest.raises(ValueError, match="finite"):
        make_fault(kind, value, np.random.default_rng(0))
