from __future__ import annotations

from vecu.clock import NS_PER_MS
from vecu.ecu.sensor_monitor import (
    DtcState,
    SensorMonitor,
    SensorMonitorConfig,
    SensorStatus,
)
from vecu.models.sensors import TpsCalibration

CAL = TpsCalibration()


def feed(mon, volts, start_ms=0, est=None, std=2.0):
    """One frame per ms; returns the status after each tick."""
    out = []
    for k, v in enumerate(volts):
        t = (start_ms + k) * NS_PER_MS
        if v is not None:
            mon.on_frame(t, v)
        out.append(mon.evaluate(t, CAL.angle(v) if est is None and v is not None else (est or 0.0), std))
    return out


def noisy(n, base=2.0, step=0.003):
    return [base + step * ((k * 7919) % 13 - 6) for k in range(n)]


def test_healthy_sensor_stays_ok_and_dtc_none():
    mon = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    assert set(feed(mon, noisy(500))) == {SensorStatus.OK}
    assert mon.dtc == DtcState.NONE


def test_frames_stop_is_confirmed_at_the_third_missed_period():
    mon = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    st = feed(mon, noisy(10) + [None] * 5)
    assert st[10:] == [SensorStatus.OK, SensorStatus.OK, SensorStatus.TIMEOUT, SensorStatus.TIMEOUT,
                       SensorStatus.TIMEOUT]
    assert mon.first_fault_ns == 12 * NS_PER_MS  # last frame at 9 ms; 3 periods later


def test_open_circuit_and_short_are_range_faults_within_debounce():
    mon = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    st = feed(mon, noisy(10) + [0.0] * 3)
    assert st[10] == SensorStatus.OK and st[11] == SensorStatus.RANGE_LOW
    mon2 = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    assert feed(mon2, noisy(10) + [5.0] * 3)[11] == SensorStatus.RANGE_HIGH


def test_stuck_value_is_detected_after_configured_samples():
    cfg = SensorMonitorConfig()
    mon = SensorMonitor.for_tps(cfg, CAL)
    st = feed(mon, noisy(10) + [2.2] * 12)
    first = st.index(SensorStatus.STUCK)
    assert first == 10 + cfg.stuck_samples - 1


def test_e2e_errors_debounced():
    mon = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    feed(mon, noisy(5))
    mon.on_e2e_error()
    assert mon.evaluate(5 * NS_PER_MS, 27.0, 2.0) == SensorStatus.OK
    mon.on_e2e_error()
    assert mon.evaluate(6 * NS_PER_MS, 27.0, 2.0) == SensorStatus.E2E_ERROR


def test_implausible_against_estimate_then_heals_after_clean_period():
    cfg = SensorMonitorConfig()
    mon = SensorMonitor.for_tps(cfg, CAL)
    volts = noisy(3000)
    # estimator says 60 deg while the sensor says ~34 deg for 20 ms
    st = []
    for k, v in enumerate(volts):
        t = k * NS_PER_MS
        mon.on_frame(t, v)
        est = 60.0 if 100 <= k < 120 else CAL.angle(v)
        st.append(mon.evaluate(t, est, 2.0))
    assert st[100 + cfg.plaus_debounce - 1] == SensorStatus.IMPLAUSIBLE
    assert st[99] == SensorStatus.OK
    assert mon.dtc == DtcState.CONFIRMED
    healed = st.index(SensorStatus.OK, 120)
    assert abs(healed - (120 + cfg.heal_ms)) <= cfg.plaus_debounce + 1


def test_select_broadcasts_sensor_while_ok_then_estimate_and_counts_one_timeout():
    from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE, SOURCE_SENSOR

    mon = SensorMonitor.for_tps(SensorMonitorConfig(), CAL)
    out = []
    for k in range(20):
        t = k * NS_PER_MS
        if k < 10:
            mon.on_frame(t, 2.0 + 0.001 * (k % 3))
        out.append(mon.select(t, 40.0, 3.0))
    # frames stop after 9 ms: the last valid angle is held until the timeout confirms at 12 ms
    assert [src for _, src, _ in out[:12]] == [SOURCE_SENSOR] * 12
    assert out[9][0] == out[11][0] == CAL.angle(2.0)
    assert [src for _, src, _ in out[12:]] == [SOURCE_ESTIMATE] * 8
    assert all(v == 40.0 for v, _, _ in out[12:])
    assert mon.timeouts == 1
