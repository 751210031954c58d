from __future__ import annotations

import numpy as np
import pytest

from vecu.clock import NS_PER_MS
from vecu.faults import FaultKind, FaultTarget, make_fault, parse_kind


@pytest.fixture
def rig(plant_rig):
    return plant_rig("plant-test")


def tps_voltages(codec, tester):
    out = []
    while (m := tester.recv(0.0)) is not None:
        if m.arbitration_id == codec["TPS_Sensor"].frame_id:
            out.append(codec["TPS_Sensor"].decode(m.data)["TPS_Voltage"])
    return out


def test_fault_command_frame_on_the_bus_kills_and_clears_the_tps(rig):
    codec, node, tester, inj = rig
    fi = codec["FI_Command"]
    for k in range(5):
        node.tick(k * NS_PER_MS)
    assert len(tps_voltages(codec, tester)) == 5
    tester.send(fi.frame({"FI_Target": 1, "FI_Kind": int(FaultKind.DEAD), "FI_Value": 0.0}, 0.005))
    node.tick(5 * NS_PER_MS)
    assert tps_voltages(codec, tester) == [0.0]
    assert inj.events[-1].source == "can" and inj.active(FaultTarget.TPS) == FaultKind.DEAD
    tester.send(fi.frame({"FI_Target": 1, "FI_Kind": int(FaultKind.FRAMES_STOP), "FI_Value": 0}, 0.006))
    node.tick(6 * NS_PER_MS)
    assert tps_voltages(codec, tester) == []
    tester.send(fi.frame({"FI_Target": 1, "FI_Kind": 0, "FI_Value": 0}, 0.007))
    node.tick(7 * NS_PER_MS)
    assert len(tps_voltages(codec, tester)) == 1 and inj.active(FaultTarget.TPS) is None


def test_bad_fault_commands_are_counted_not_fatal(rig):
    codec, node, tester, inj = rig
    fi = codec["FI_Command"]
    tester.send(fi.frame({"FI_Target": 99, "FI_Kind": 1, "FI_Value": 0}, 0.0))
    tester.send(fi.frame({"FI_Target": 1, "FI_Kind": 200, "FI_Value": 0}, 0.0))
    tester.send(fi.frame({"FI_Target": 1, "FI_Kind": int(FaultKind.GAIN), "FI_Value": 5.0}, 0.0))
    node.tick(0)
    assert inj.rejected_commands == 3 and inj.active(FaultTarget.TPS) is None


@pytest.mark.parametrize("kind,value,check", [
    (FaultKind.DEAD, None, lambda out, v: out == 0.0),
    (FaultKind.SHORT_SUPPLY, None, lambda out, v: out == 5.0),
    (FaultKind.OFFSET, 0.3, lambda out, v: out == pytest.approx(v + 0.3)),
    (FaultKind.GAIN, 0.25, lambda out, v: out == pytest.approx(0.25 * v)),
    (FaultKind.FRAMES_STOP, None, lambda out, v: out is None),
])
def test_fault_kinds_transform_the_signal(kind, value, check):
    f = make_fault(kind, value, np.random.default_rng(0))
    for v in (0.7, 2.5, 4.1):
        assert check(f.apply(v), v)


def test_stuck_holds_first_value_and_noise_is_seeded():
    f = make_fault(FaultKind.STUCK, None, np.random.default_rng(0))
    assert [f.apply(v) for v in (1.0, 2.0, 3.0)] == [1.0, 1.0, 1.0]
    a = make_fault(FaultKind.NOISE, 0.2, np.random.default_rng(4))
    b = make_fault(FaultKind.NOISE, 0.2, np.random.default_rng(4))
    xa = [a.apply(2.0) for _ in range(200)]
    assert xa == [b.apply(2.0) for _ in range(200)]
    assert 0.15 < float(np.std(xa)) < 0.25


def test_parse_kind_accepts_cli_spellings_and_rejects_unknown():
    assert parse_kind("frames-stop") == FaultKind.FRAMES_STOP
    with pytest.raises(ValueError, match="unknown fault kind"):
        parse_kind("explode")


def test_manifold_events_computed_ahead_are_the_same_under_both_backends():
    """ManifoldPart computes its events ahead in blocks (EventsAhead: truth_events, compiled
    or as Python): the same frames, times and truth under both backends, across block refills,
    noise blocks and the switches to the next legs of the drive (vecu.plant.drive: one profile
    per manoeuvre). truth_events against the event-by-event loop: tests/plant/test_manifold.py."""
    pytest.importorskip("numba")
    from vecu.codec import shared_codec
    from vecu.kernels import using
    from vecu.plant.node import ManifoldPart

    codec = shared_codec()
    runs = []
    for backend in ("numba", "python"):
        with using(backend):
            part = ManifoldPart(codec, seed=3)
            part.truth_msg = codec["TRUTH_Manifold"]
            sent: list[tuple[float, int, bytes]] = []

            def send(m, sent=sent):
                sent.append((m.timestamp, m.arbitration_id, bytes(m.data)))
                return True

            t_ns, times = 0, []
            while part._profile_index < 3 or len(times) % 300:  # into the fourth leg
                times.append(t_ns)
                t_ns = part.event(t_ns, send)
        runs.append((sent, times, dict(part.truth)))
    assert len(runs[0][1]) > 2 * 1024  # past two noise blocks (ManifoldPlantConfig.block)
    assert runs[0] == runs[1]


def test_throttle_ticks_computed_ahead_send_what_stepping_sends(backend):
    """ThrottlePart computes its ticks ahead in blocks (ThrottlePlant.ticks) and encodes their
    frames in blocks: the same frames and probe values as stepping eq. (3) tick by tick
    (plant_step as plain Python on the same noise stream) and making each frame with the
    framers, across block refills and noise blocks, with TPS faults on the way (a changed
    voltage, no frames for a while)."""
    from vecu.codec import shared_codec
    from vecu.faults import FaultInjector
    from vecu.models.sensors import TpsCalibration
    from vecu.plant.throttle import (
        TPS_SIGNALS,
        WATT_SIGNALS,
        InputConfig,
        InputGenerator,
        ThrottlePart,
        ThrottlePlant,
        ThrottlePlantConfig,
        plant_step,
    )
    from vecu.rng import rng_streams

    codec = shared_codec()
    cal = TpsCalibration(v_at_0=0.0, v_at_90=5.0)  # the paper's 0-5 V law: clamped at the stops
    cfg = ThrottlePlantConfig()
    commands = {700: (int(FaultKind.NOISE), 0.2), 1300: (0, 0.0), 1620: (0, 0.0),
                1590: (int(FaultKind.FRAMES_STOP), 0.0)}  # 30 ticks without TPS frames

    def run(tick):
        rngs = rng_streams(5, ("i", "p", "f"))
        inj = FaultInjector(rngs["f"])
        sent, seen = [], []
        state = tick(rngs, inj)
        for k in range(2600):  # 5 blocks ahead, 2 noise blocks
            if k in commands:
                assert inj.on_command(k * NS_PER_MS, int(FaultTarget.TPS), *commands[k])
            seen.append(state(k * NS_PER_MS, lambda m: sent.append(
                (m.timestamp, m.arbitration_id, bytes(m.data))) or True))
        return sent, seen

    def part(rngs, inj):
        p = ThrottlePart(codec, ThrottlePlant(cfg, rngs["p"]),
                         InputGenerator(InputConfig(), rngs["i"]), inj, cal)
        p.truth_msg = codec["TRUTH_Throttle"]

        def tick(t_ns, send):
            p.tick(t_ns, send)
            return p.theta, p.u, p.tps_voltage
        return tick

    def stepped(rngs, inj):  # the oracle: one tick at a time, each frame by its framer
        gen, rng = InputGenerator(InputConfig(), rngs["i"]), rngs["p"]
        tps, watt, truth = (codec[n] for n in ("TPS_Sensor", "ETB_Wattmeter", "TRUTH_Throttle"))
        make_tps, make_watt = tps.framer(TPS_SIGNALS), watt.framer(WATT_SIGNALS)
        m = cfg.model
        x, noise, st = [0.0, 0.0, 0.0], [], {"counter": 0}

        def tick(t_ns, send):
            if not noise:
                noise.extend(rng.standard_normal((cfg.block, 4)).tolist()[::-1])
            w, u, ts = noise.pop(), gen.next(), t_ns / 1e9
            theta, rho, i = x
            v = inj.apply(FaultTarget.TPS, cal.voltage(theta) + cfg.tps_noise_v * w[3])
            if v is not None:
                v = min(max(v, 0.0), 5.0)
                send(make_tps(ts, 0, st["counter"], v)[0])
                st["counter"] = (st["counter"] + 1) % 15
            send(make_watt(ts, u, i * i + m.h_wattmeter * w[2])[0])
            send(truth.frame({"TRU_ThrottleAngle": theta, "TRU_MotorVoltage": u}, ts))
            x[:] = plant_step.py(m.rows, *m.mode_bounds_deg, cfg.noise_scale * m.f_diag[0],
                                 cfg.noise_scale * m.f_diag[2], theta, rho, i, u, w[0], w[1])
            return theta, u, v
        return tick

    ahead, oracle = run(part), run(stepped)
    assert len(ahead[0]) > 7000
    assert any(v == 0.0 for _, _, v in oracle[1])  # a clamped voltage was among them
    assert ahead == oracle


def test_longitudinal_frames_encoded_per_manoeuvre_are_the_framers():
    """LongitudinalPart encodes a whole manoeuvre's ESC_Motion payloads at once: each frame it
    sends is the framer's for that tick's sensor values, into the next manoeuvre too."""
    from vecu.codec import shared_codec
    from vecu.plant.drive import LongitudinalPart
    from vecu.units import MPS_PER_KMH

    codec = shared_codec()
    part = LongitudinalPart(codec, 3, ("paper", "launch_brake"))
    first = len(part._cols[0])
    assert all(p is not None for p in part._payloads)  # all encoded in the block
    make = codec["ESC_Motion"].framer(("ESC_WheelSpeed", "ESC_LongAccel"))
    sent = []
    for k in range(first + 300):
        part.tick(2 * k * NS_PER_MS, lambda m: sent.append(m) or True)
        want = make(sent[-1].timestamp, part.wheel / MPS_PER_KMH, part.accel)[0]
        assert bytes(sent[-1].data) == bytes(want.data), k
        assert (sent[-1].arbitration_id, sent[-1].dlc, sent[-1].is_extended_id) == (
            want.arbitration_id, want.dlc, want.is_extended_id)
    assert part._leg.index == 1 and len({bytes(m.data) for m in sent}) > first // 2


@pytest.mark.parametrize("kind", [FaultKind.DEAD, FaultKind.STUCK, FaultKind.NOISE])
def test_tps_frames_of_a_fault_are_the_framers(kind, backend):
    """A fault's TPS voltages go out as the framer makes them, counter after counter."""
    from vecu.codec import shared_codec
    from vecu.faults import FaultInjector
    from vecu.plant.throttle import (
        InputConfig,
        InputGenerator,
        ThrottlePart,
        ThrottlePlant,
        ThrottlePlantConfig,
    )
    from vecu.rng import rng_streams

    codec = shared_codec()
    tps = codec["TPS_Sensor"]
    make = tps.framer(("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage"))
    rngs = rng_streams(3, ("i", "p", "f"))
    inj = FaultInjector(rngs["f"])
    part = ThrottlePart(codec, ThrottlePlant(ThrottlePlantConfig(), rngs["p"]),
                        InputGenerator(InputConfig(), rngs["i"]), inj)
    sent = []
    for k in range(200):
        if k == 20:
            assert inj.on_command(k * NS_PER_MS, int(FaultTarget.TPS), int(kind), 0.2)
        part.tick(k * NS_PER_MS, lambda m: sent.append(m) or True)
    frames = [m for m in sent if m.arbitration_id == tps.frame_id][20:]
    assert len(frames) == 180
    counters = []
    for m in frames:
        values = tps.decode(m.data)
        counters.append(int(values["TPS_AliveCounter"]))
        ref = make(m.timestamp, 0, counters[-1], values["TPS_Voltage"])[0]
        assert bytes(m.data) == bytes(ref.data)
    assert all((b - a) % 15 == 1 for a, b in zip(counters, counters[1:]))
    if kind != FaultKind.NOISE:
        assert len({bytes(m.data) for m in frames}) == 15  # one payload per counter value
