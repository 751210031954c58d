"""The adaptive manifold EKF (vecu.estimators.manifold.adaptive): its eta correction c converges
to the plant's volumetric-efficiency error, the CAC prediction then beats the EKF's, and in the
ECU it broadcasts c, its sigma and the throttle-flow correction (ECU_ManifoldAdapt) — only when
it is the selected filter."""

from __future__ import annotations

import dataclasses

import can
import numpy as np
import pytest

from vecu.bus import open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.ecu.manifold_function import ManifoldFunction, ManifoldFunctionConfig
from vecu.ecu.node import EcuNode
from vecu.estimators.manifold.cac_predict import CacPredictionConfig, prediction_errors
from vecu.estimators.manifold.factory import make_filter
from vecu.eval.manifold import trace_input_array
from vecu.models.manifold import nominal_input, steady_state
from vecu.models.manifold_params import V8_5L7
from vecu.plant.drive_profile import DriveProfile, us06_like
from vecu.plant.manifold import ManifoldPlantConfig, simulate

CONVERGED_BY_S = 5.0  # stated convergence time on the US06-like drive
TOLERANCE = 0.01  # |c - c_true|: within one percentage point of the true error


def _drive(eps: float, seconds: float = 25.0, seed: int = 3):
    eng = dataclasses.replace(V8_5L7, eta_n_val=tuple(v * (1.0 + eps) for v in V8_5L7.eta_n_val))
    p = us06_like(seed)
    k = round(seconds / p.dt_s) + 1
    prof = DriveProfile(p.dt_s, p.n_rpm[:k], p.ta_sp[:k])
    return simulate(prof, seed=seed, params=eng, config=ManifoldPlantConfig(engine=eng))


@pytest.fixture(scope="module", params=[0.04, -0.04])
def eta_error(request):
    trace = _drive(request.param)
    us = trace_input_array(trace)
    states = {}
    for name in ("ekf", "adaptive"):
        states[name] = make_filter(name).run_events(trace.y, us)
    return request.param, trace, states


def test_eta_correction_converges_to_the_true_error(eta_error):
    eps, trace, states = eta_error
    c = states["adaptive"][:, 6]
    late = trace.t >= CONVERGED_BY_S
    assert np.all(np.isfinite(states["adaptive"]))
    assert np.max(np.abs(c[late] - (1.0 + eps))) <= TOLERANCE, (eps, c[late].min(), c[late].max())
    assert abs(c[0] - 1.0) < 0.005  # it starts at the calibration


def test_cac_prediction_beats_the_ekf_when_eta_is_off(eta_error):
    _, trace, states = eta_error
    cfg = CacPredictionConfig(stride=2)
    iae = {}
    for name, xs in states.items():
        scale = xs[:, 6] if name == "adaptive" else None
        _, pred, actual = prediction_errors(xs, trace.ta_sp, trace.n_rpm, trace.cac, config=cfg,
                                            eta_scale=scale)
        iae[name] = float(np.abs(pred - actual).sum())
    assert iae["adaptive"] < 0.5 * iae["ekf"], iae


@pytest.mark.parametrize("filt", ["adaptive", "sdkf"])
def test_ecu_broadcasts_the_correction_only_with_the_adaptive_filter(request, filt):
    codec = DbcCodec()
    ev, intake, adapt = codec["ENG_Event"], codec["ENG_Intake"], codec["ECU_ManifoldAdapt"]
    channel = f"adaptive-{request.node.name}"
    ecu_bus, tester = open_bus(channel=channel), open_bus(channel=channel)
    try:
        ecu = EcuNode(ecu_bus, codec, [ManifoldFunction(codec, ManifoldFunctionConfig(filt))])
        angle = 12.0
        p_ss, t_ss = steady_state(np.radians(angle), nominal_input(np.radians(angle), 2000.0))
        for k in range(40):
            tester.send(can.Message(arbitration_id=ev.frame_id, is_extended_id=False, data=ev.encode(
                {"ENG_EventCounter": k, "ENG_Speed": 2000.0, "ENG_ThrottleSetpoint": angle,
                 "ENG_ThrottleAngle": angle, "ENG_MAP": p_ss})))
            tester.send(can.Message(arbitration_id=intake.frame_id, is_extended_id=False,
                                    data=intake.encode({"ENG_IntakeCounter": k,
                                                        "ENG_IAT": t_ss - 273.15})))
            ecu.tick(k * NS_PER_MS)
        got = []
        while (m := tester.recv(0.0)) is not None:
            if m.arbitration_id == adapt.frame_id:
                got.append(adapt.decode(m.data))
    finally:
        ecu_bus.shutdown()
        tester.shutdown()
    if filt == "sdkf":
        assert got == []
        return
    assert len(got) == 40
    # the engine is the calibrated one at a steady state: c stays near 1, its sigma shrinks
    assert all(abs(g["MFD_EtaCorr"]) < 5.0 and 0.0 < g["MFD_EtaCorrStd"] <= 5.1 for g in got)
    assert all(abs(g["MFD_EtaCorr"]) < 0.5 for g in got[-10:]), got[-10:]
    assert got[-1]["MFD_EtaCorrStd"] < got[0]["MFD_EtaCorrStd"]  # it learns
