"""Issue 30 item 1: every estimate message carries its sigma and a validity (vecu.ecu.validity)
that says init until its filter has been initialised from the first measurements, not a
confident wrong value; the replay scoring skips what the ECU flags init / invalid."""

from __future__ import annotations

import math

import can
import cantools
import pytest

from vecu import functions
from vecu.bus import open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec, builtin_dbc_path
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.ecu.validity import DEGRADED, INIT, INVALID, SCORED, VALID, VALUE_TABLE, Validity
from vecu.replay.scoring import TruthScorer

CODEC = DbcCodec()
DBC = cantools.database.load_file(builtin_dbc_path())
CONFIG = RunConfig(duration_s=10.0, kill_tps_at_s=None)


class Rig:
    """One ECU function on a fresh virtual channel; the tester sends frames, ticks the ECU and
    reads what the function broadcast, decoded."""

    def __init__(self, name: str, channel: str) -> None:
        self.fn = functions.spec(name).build(CONFIG, CODEC, None)
        self.ecu_bus, self.tester = open_bus(channel=channel), open_bus(channel=channel)
        self.ecu = EcuNode(self.ecu_bus, CODEC, [self.fn])
        self.t_ns = 0

    def frame(self, name: str, values: dict[str, float]) -> None:
        fc = CODEC[name]
        self.tester.send(can.Message(arbitration_id=fc.frame_id, is_extended_id=False,
                                     data=fc.encode(values)))

    def tick(self, ms: int = 1) -> dict[str, list[dict[str, float]]]:
        out: dict[str, list[dict[str, float]]] = {}
        for _ in range(ms):
            self.ecu.tick(self.t_ns)
            self.t_ns += NS_PER_MS
        while (m := self.tester.recv(0.0)) is not None:
            fc = CODEC.lookup(m)
            assert fc is not None
            out.setdefault(fc.name, []).append(fc.decode(m.data))
        return out

    def close(self) -> None:
        self.ecu_bus.shutdown()
        self.tester.shutdown()


@pytest.fixture
def rig(request):
    made: list[Rig] = []

    def make(name: str) -> Rig:
        r = Rig(name, f"validity-{request.node.name}-{name}")
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


def test_one_enum_is_the_dbc_value_table_of_every_validity_signal():
    for msg, sig in (("ECU_ThrottleEstimate", "THR_Validity"), ("ECU_SpeedEstimate", "SPD_Validity"),
                     ("ECU_SteeringEstimate", "STE_Validity"),
                     ("ECU_SteeringSmoothed", "STS_Validity"), ("ECU_ManifoldSigma", "MFD_Validity")):
        choices = DBC.get_message_by_name(msg).get_signal_by_name(sig).choices
        assert {int(k): str(v) for k, v in choices.items()} == VALUE_TABLE, (msg, sig)
    assert SCORED == {VALID, DEGRADED} and INIT == 0 and INVALID == 3 == Validity.INVALID


def motion(rig: Rig, kmh: float, accel: float = 0.0) -> None:
    rig.frame("ESC_Motion", {"ESC_WheelSpeed": kmh, "ESC_LongAccel": accel})


def test_speed_says_init_until_the_first_wheel_frame_then_starts_from_it(rig):
    r = rig("speed")
    # the ECU runs before the first ESC_Motion frame (4 ms: inside the receive deadline)
    frames = r.tick(4)["ECU_SpeedEstimate"]
    assert len(frames) == 2
    for f in frames:  # not "0 km/h, standstill, sigma 0.02"
        assert f["SPD_Validity"] == INIT and f["SPD_Mode"] != 1
        assert f["SPD_VehSpeedStd"] >= 5.0  # the prior's sigma (saturated), not a tiny one
    motion(r, 87.0)
    first = r.tick(2)["ECU_SpeedEstimate"][-1]
    assert first["SPD_Validity"] == VALID and first["SPD_Mode"] == 0
    assert first["SPD_VehSpeed"] == pytest.approx(87.0, abs=0.02)
    assert 1.0 < first["SPD_VehSpeedStd"] < 1.5  # the sensor's 0.35 m/s = 1.26 km/h
    assert 0.0 < first["SPD_VehAccelStd"] <= 5.1
    for _ in range(50):
        motion(r, 87.0)
        last = r.tick(2)["ECU_SpeedEstimate"][-1]
    assert last["SPD_Validity"] == VALID and abs(last["SPD_VehSpeed"] - 87.0) < 3 * max(
        last["SPD_VehSpeedStd"], 0.02)
    assert r.fn.validity == VALID


def test_speed_coasting_on_a_dead_wheel_sensor_is_degraded(rig):
    r = rig("speed")
    for _ in range(20):
        motion(r, 80.0)
        r.tick(2)
    for _ in range(40):  # frames stop: timeout, the filter coasts on nothing but prediction
        last = r.tick(2)["ECU_SpeedEstimate"][-1]
    assert last["SPD_Mode"] == 3 and last["SPD_Validity"] == DEGRADED


def engine(r: Rig, counter: int, map_kpa: float = 85.0, iat_c: float | None = 30.0,
           rpm: float = 2000.0, angle: float = 30.0) -> None:
    r.frame("ENG_Event", {"ENG_EventCounter": counter, "ENG_Speed": rpm,
                          "ENG_ThrottleSetpoint": angle, "ENG_ThrottleAngle": angle,
                          "ENG_MAP": map_kpa})
    if iat_c is not None:
        r.frame("ENG_Intake", {"ENG_IntakeCounter": counter, "ENG_IAT": iat_c})


def test_manifold_starts_from_its_first_readings_with_honest_sigmas(rig):
    r = rig("manifold")
    engine(r, 0, map_kpa=85.0)  # at cruise, far from the 25 kPa idle point
    out = r.tick()
    sig, est = out["ECU_ManifoldSigma"][0], out["ECU_ManifoldEstimate"][0]
    assert sig["MFD_Validity"] == VALID and sig["MFD_EventCounter"] == 0
    assert abs(est["MFD_Pressure"] - 85.0) < 3 * sig["MFD_PressureStd"] + 0.02
    assert abs(est["MFD_Temperature"] - 30.0) < 3 * sig["MFD_TemperatureStd"] + 0.2
    for name in ("MFD_ThrottleAngleStd", "MFD_PressureStd", "MFD_TemperatureStd", "MFD_CACStd",
                 "MFD_CACPred6Std"):
        assert math.isfinite(sig[name]) and sig[name] > 0.0, name
    # the CAC sigma is the P_im sigma through CAC ~ P: same relative size (eta(P) adds a bit)
    rel_p = sig["MFD_PressureStd"] / est["MFD_Pressure"]
    assert sig["MFD_CACStd"] / est["MFD_CAC"] >= rel_p
    for k in range(1, 30):
        engine(r, k)
        out = r.tick(9)
    sig = out["ECU_ManifoldSigma"][0]
    assert sig["MFD_Validity"] == VALID and sig["MFD_EventCounter"] == 29
    # the prediction 6 events ahead knows less than the estimate now
    assert sig["MFD_CACPred6Std"] > sig["MFD_CACStd"] > 0.0
    assert r.fn.validity == VALID


def test_manifold_without_a_complete_first_event_says_init_then_degraded_on_a_missing_iat(rig):
    r = rig("manifold")
    engine(r, 0, iat_c=None)
    assert r.tick()["ECU_ManifoldSigma"][0]["MFD_Validity"] == INIT
    engine(r, 1)
    assert r.tick(9)["ECU_ManifoldSigma"][0]["MFD_Validity"] == VALID
    engine(r, 2, iat_c=None)
    assert r.tick(9)["ECU_ManifoldSigma"][0]["MFD_Validity"] == DEGRADED


def lateral(r: Rig, kmh: float, yaw: float = 0.0, ay: float = 0.0) -> None:
    r.frame("CHS_Lateral", {"LAT_YawRate": yaw, "LAT_LatAccel": ay, "LAT_VehSpeed": kmh})
    r.frame("SWA_Sensor", {"SWA_CRC": 0, "SWA_AliveCounter": 0, "SWA_Angle": 0.0})


def test_steering_is_init_then_degraded_with_a_large_sigma_at_standstill(rig):
    r = rig("steering")
    out = r.tick(10)
    assert out["ECU_SteeringEstimate"][0]["STE_Validity"] == INIT
    assert out["ECU_SteeringSmoothed"][0]["STS_Validity"] == INIT
    for _ in range(100):  # 1 s at rest
        lateral(r, 0.0)
        out = r.tick(10)
    est, sig = out["ECU_SteeringEstimate"][0], out["ECU_SteeringSigma"][0]
    assert est["STE_Validity"] == DEGRADED
    assert sig["STE_SwAngleEstStd"] > 20.0  # unobservable: not the UKF's ~1 deg
    assert out["ECU_SteeringSmoothed"][0]["STS_Validity"] == DEGRADED
    for _ in range(100):  # 1 s straight at 80 km/h
        lateral(r, 80.0)
        out = r.tick(10)
    est, sig = out["ECU_SteeringEstimate"][0], out["ECU_SteeringSigma"][0]
    assert est["STE_Validity"] == VALID and out["ECU_SteeringSmoothed"][0]["STS_Validity"] == VALID
    assert 0.0 < sig["STE_SwAngleEstStd"] < 10.0 and 0.0 < sig["STE_SideSlipStd"] < 1.0
    assert abs(est["STE_SwAngleEst"]) < 3 * sig["STE_SwAngleEstStd"]


def test_throttle_is_init_before_the_first_wattmeter_reading_and_degraded_without_them(rig):
    r = rig("throttle")
    assert r.tick(3)["ECU_ThrottleEstimate"][-1]["THR_Validity"] == INIT
    for _ in range(5):
        r.frame("ETB_Wattmeter", {"ETB_Voltage": 1.0, "ETB_Power": 0.5})
        last = r.tick()["ECU_ThrottleEstimate"][-1]
    assert last["THR_Validity"] == VALID and last["THR_AngleEstStd"] > 0.0
    assert r.tick(3)["ECU_ThrottleEstimate"][-1]["THR_Validity"] == DEGRADED


def test_uds_validity_dids_read_what_the_broadcast_says(rig):
    for name, did in (("speed", 0x030F), ("throttle", 0x010F), ("steering", 0x040F),
                      ("manifold", 0x020F)):
        r = rig(name)
        r.tick(10)
        d = next(d for d in r.fn.dids() if d.did == did)
        assert d.decode(d.value()) == r.fn.validity == INIT, name


def test_replay_scoring_skips_and_counts_init_frames():
    scorer = TruthScorer(CODEC)
    truth, est = CODEC["TRUTH_Speed"], CODEC["ECU_SpeedEstimate"]

    def msg(fc, values):
        return can.Message(arbitration_id=fc.frame_id, is_extended_id=False,
                           data=fc.encode(values))

    base = {"SPD_VehAccel": 0.0, "SPD_VehSpeedStd": 1.0, "SPD_AccelOffset": 0.0, "SPD_Mode": 0,
            "SPD_VehAccelStd": 0.5}
    frame = est.framer([s.name for s in est.signals])  # as the ECU sends it: frame and values
    for k in range(400, 420):  # after the speed burn-in
        t = k * 2 * NS_PER_MS
        scorer.on_truth(msg(truth, {"TRU_VehSpeed": 87.0, "TRU_VehAccel": 0.0}), t)
        validity, speed = (INIT, 0.0) if k < 410 else (VALID, 87.5)
        values = {**base, "SPD_VehSpeed": speed, "SPD_Validity": validity}
        sent, carried = frame(t / 1e9, *(values.get(s.name, 0) for s in est.signals))
        scorer.on_estimate(carried, sent, t)
    section = scorer.summary().functions["speed"]
    assert section.not_valid_estimates == 10
    err = section.errors["speed_error_kmh"]
    assert err.n == 10 and err.rms == pytest.approx(0.5)
