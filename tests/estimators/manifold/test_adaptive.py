"""The adaptive manifold EKF (vecu.estimators.manifold.adaptive): its eta correction c converges
to the plant's volumetric-efficiency error, the CAC prediction then beats the EKF's, and in the
ECU it broadcasts the correction, its sigma, the throttle-flow correction and what it learned of
the throttle (ECU_ManifoldAdapt) — only when it is the selected filter."""

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

CONVERGED_BY_S = 30.0  # stated convergence time on the US06-like drive (docs/models.md)
TOLERANCE = 0.01  # |c - c_true|: within one percentage point of the true error


def _drive(eps: float, seconds: float = 40.0, seed: int = 3, **engine):
    """A drive of the engine with eta scaled by 1 + eps (and `engine`'s other differences)."""
    eng = dataclasses.replace(V8_5L7, eta_n_val=tuple(v * (1.0 + eps) for v in V8_5L7.eta_n_val),
                              **engine.pop("params", {}))
    p = us06_like(seed)
    k = round(seconds / p.dt_s) + 1
    prof = DriveProfile(p.dt_s, p.n_rpm[:k], p.ta_sp[:k])
    return simulate(prof, seed=seed, params=eng, config=ManifoldPlantConfig(engine=eng, **engine))


def _run(trace, names=("ekf", "adaptive")):
    """Posteriors per filter, and the adaptive filter's eta correction as the CAC uses it."""
    us = trace_input_array(trace)
    states, used = {}, None
    for name in names:
        flt = make_filter(name)
        states[name] = flt.run_events(trace.y, us)
        if name == "adaptive":
            used = flt.eta_used(states[name][:, 6], flt.run_variances[:, 6])
    return states, used


def _iae(trace, xs, scale=None):
    _, pred, actual = prediction_errors(xs, trace.ta_sp, trace.n_rpm, trace.cac,
                                        config=CacPredictionConfig(stride=2), eta_scale=scale)
    return float(np.abs(pred - actual).sum())


@pytest.fixture(scope="module", params=[0.04, -0.04])
def eta_error(request):
    trace = _drive(request.param)
    return (request.param, trace, *_run(trace))


def test_eta_correction_converges_to_the_true_error(eta_error):
    eps, trace, states, used = eta_error
    c = states["adaptive"][:, 6]
    late = trace.t >= CONVERGED_BY_S
    assert np.all(np.isfinite(states["adaptive"])) and np.all(np.isfinite(used))
    for name, v in (("c", c), ("the correction used", used)):
        assert np.max(np.abs(v[late] - (1.0 + eps))) <= TOLERANCE, (name, eps, v[late].min(),
                                                                     v[late].max())
    assert abs(c[0] - 1.0) < 0.005  # it starts at the calibration
    assert abs(used[-1] - 1.0) > 0.03  # the evidence outweighs the "calibrated engine" prior


def test_cac_prediction_beats_the_ekf_when_eta_is_off(eta_error):
    _, trace, states, used = eta_error
    iae = {"ekf": _iae(trace, states["ekf"]), "adaptive": _iae(trace, states["adaptive"], used)}
    assert iae["adaptive"] < 0.5 * iae["ekf"], iae


def test_it_learns_the_angle_sensor_gain_and_the_actuator():
    """Table 2's throttle errors at their limits (TA gain +3 %, zeta_T +5 %, omega_T -5 %,
    eta as calibrated): g, k_zeta, k_omega converge to them and c is not pulled away from 1
    (before these states, such errors biased c by 1-3 %)."""
    eng = {"zeta": V8_5L7.zeta * 1.05, "omega0": V8_5L7.omega0 * 0.95}
    trace = _drive(0.0, seconds=60.0, seed=5, params=eng, sensor_gains=(1.03, 1.0, 1.0))
    states, used = _run(trace, ("adaptive",))
    x = states["adaptive"][-1]
    assert abs(x[8] - 1.03) < 0.005, x[8]  # g: TA = g alpha
    assert abs(x[9] - 1.05) < 0.02, x[9]  # k_zeta
    assert abs(x[10] - 0.95) < 0.02, x[10]  # k_omega
    late = trace.t >= CONVERGED_BY_S
    assert np.max(np.abs(states["adaptive"][late, 6] - 1.0)) < TOLERANCE
    assert np.max(np.abs(used[late] - 1.0)) < 0.005


def test_without_mismatch_it_is_as_good_as_the_sdkf():
    """The engine is the calibrated one: the CAC prediction error is within 5 % of the SDKF's
    (the spike-and-slab correction stays near 1 where the evidence is weak)."""
    trace = _drive(0.0, seconds=80.0, seed=11)
    states, used = _run(trace, ("sdkf", "adaptive"))
    iae_sdkf, iae_ad = _iae(trace, states["sdkf"]), _iae(trace, states["adaptive"], used)
    assert iae_ad <= 1.05 * iae_sdkf, (iae_ad, iae_sdkf)
    raw = _iae(trace, states["adaptive"], states["adaptive"][:, 6])  # c as it is: worse
    assert raw > iae_ad


@pytest.mark.parametrize(("c", "var", "p", "want"), [
    (1.03, 1e-6, 0.2, (1.029, 1.030)),  # strong evidence: c, barely shrunk
    (1.004, 1.6e-5, 0.2, (1.0, 1.001)),  # c - 1 = 1 sigma: the calibration wins
    (1.03, 1e-6, 0.0, (1.0, 1.0)),  # the engine is the calibrated one, whatever c says
    (0.97, 1e-4, 1.0, (0.9759, 0.9761)),  # always drifted: Gaussian shrinkage s^2 / (s^2 + var)
    (1.0, 2.5e-3, 0.2, (1.0, 1.0)),
])
def test_eta_scale_used_is_the_spike_and_slab_posterior_mean(c, var, p, want):
    from vecu.estimators.manifold.adaptive import eta_scale_used

    got = eta_scale_used(c, var, p, 0.02)
    assert want[0] <= got <= want[1], got
    arr = eta_scale_used(np.array([c, 1.0]), np.array([var, var]), p, 0.02)
    assert arr[0] == pytest.approx(got) and arr[1] == 1.0


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
    # and what it learned of the throttle: TA reads alpha (g = 1), the actuator as calibrated
    for name in ("MFD_TaGainCorr", "MFD_ActZetaCorr", "MFD_ActOmegaCorr"):
        assert all(abs(g[name]) < 1.0 for g in got), name
