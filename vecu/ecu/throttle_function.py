"""ECU throttle function: hot-standby angle estimate from the wattmeter, TPS diagnosis, broadcast.

Every 1 ms: step the estimator from the wattmeter and commanded voltage only, diagnose the TPS,
and send ECU_ThrottleEstimate carrying the sensor angle while the TPS is healthy and the
estimate otherwise, with no gap. THR_Validity (vecu.ecu.validity) qualifies the estimate: init
until the estimator has taken its first wattmeter reading, degraded while wattmeter frames have
been missing for STALE_RUNS runs (the estimator predicts only), else valid; UDS DID 0x010F.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field, replace

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.diagnostics import (
    FLOAT,
    UBYTE,
    ULONG,
    Calibrations,
    Did,
    DtcSpec,
    Variable,
    status_reader,
    validity_did,
)
from vecu.ecu.node import Send, Subscription
from vecu.ecu.sensor_monitor import (
    SOURCE_SENSOR,
    SensorMonitor,
    SensorMonitorConfig,
    SensorStatus,
)
from vecu.ecu.sensor_monitor import SensorStatus as S
from vecu.ecu.validity import DEGRADED, INIT, VALID
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.models.sensors import TpsCalibration
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel

MAX_BACKLOG = 20  # wattmeter samples the estimator catches up on in one run (20 ms of stall)
STALE_RUNS = 3  # runs in a row without a wattmeter sample: the estimate is degraded


# failure type bytes (SAE J2012-DA): 0x21/0x22 signal amplitude < min / > max, 0x64 signal
# plausibility failure, 0x83 value of signal protection calculation incorrect (CRC / alive
# counter), 0x87 missing message
DTCS: tuple[DtcSpec, ...] = (
    DtcSpec(0x012200, "tps", (S.RANGE_LOW,), "TPS A circuit low (open / short to ground)"),
    DtcSpec(0x012300, "tps", (S.RANGE_HIGH,), "TPS A circuit high (short to supply)"),
    DtcSpec(0x012100, "tps", (S.IMPLAUSIBLE, S.STUCK),
            "TPS A circuit range/performance (implausible against the estimate, or stuck)"),
    DtcSpec(0x012087, "tps", (S.TIMEOUT,), "TPS A: missing message (TPS_Sensor timeout)"),
    DtcSpec(0x012083, "tps", (S.E2E_ERROR,), "TPS A: signal protection (E2E CRC / alive counter)"),
)

@dataclass(frozen=True)
class ThrottleFunctionConfig:
    # plausibility 5 sigma + 15 deg, debounced over 300 ms (up/down counter): the estimator's
    # error is heavy-tailed (particle filter "throws" lasting 100+ ms). 5 sigma + 4 deg over 5 ms
    # gave false DTCs within minutes, 15 deg over 40 ms 16 in 1 h; 15 deg over 300 ms none in 1 h
    # (benchmarks/soak_no_false_dtc.toml). Kills are caught by range / stuck / timeout / E2E in
    # <= 7 ms; plausibility catches in-range offsets and gain faults (docs/models.md, Diagnostics)
    tps_monitor: SensorMonitorConfig = field(default_factory=lambda: SensorMonitorConfig(
        plaus_margin=15.0, plaus_debounce=300))
    calibration: TpsCalibration = field(default_factory=TpsCalibration)  # the TPS law it believes
    estimator: str = "production"  # vecu.estimators.registry name
    noise_scale: float = 1.0  # the alpha the estimator assumes for F (Q = (alpha F)^2)
    # the throttle body the estimator believes: eq. 3 modes, switching angles, F, H (Table I by
    # default; `vecu identify throttle` fits one to a trace, docs/reproduction.md)
    model: ThrottleModel = PAPER_THROTTLE


class ThrottleFunction:
    name = "throttle"
    period_ns = NS_PER_MS

    def __init__(self, codec: DbcCodec, estimator: ThrottleEstimator,
                 config: ThrottleFunctionConfig = ThrottleFunctionConfig()) -> None:
        self.estimator = estimator
        self._tps = codec["TPS_Sensor"]
        self._watt = codec["ETB_Wattmeter"]
        self._est = codec["ECU_ThrottleEstimate"]
        e2e = self._est.e2e
        assert e2e is not None, "the DBC's safety frame has no E2E layout"
        self._modulo = e2e.protection.counter_modulo  # P11: 0..14
        self._est_frame = self._est.framer((
            "THR_CRC", "THR_AliveCounter", "THR_Source", "THR_Validity", "THR_Angle",
            "THR_AngleEst", "THR_AngleEstStd", "THR_TpsStatus"))
        monitor_cfg = config.tps_monitor
        tps_cycle = self._tps.cycle_time_ms or monitor_cfg.cycle_ms
        if monitor_cfg.cycle_ms != tps_cycle:
            monitor_cfg = SensorMonitorConfig(**{**asdict(monitor_cfg), "cycle_ms": tps_cycle})
        self.monitor = SensorMonitor.for_tps(monitor_cfg, config.calibration)
        self.estimates_sent = 0      # ECU_ThrottleEstimate frames on the bus
        self.estimator_faults = 0    # non-finite estimator outputs caught here (should stay 0)
        self._tx_counter = 0
        self._u_prev = 0.0
        # wattmeter samples (u_k, y_k) since the last run: normally one; after a stall of a live
        # ECU process several, and the estimator steps once per sample to stay in step with the
        # plant (bounded: a backlog beyond MAX_BACKLOG drops the oldest, counted)
        self._samples: deque[tuple[float, float]] = deque()
        self.samples_dropped = 0
        # last broadcast, read by probes
        self.angle = 0.0
        self.source = SOURCE_SENSOR
        self.status = SensorStatus.OK
        self.validity = INIT
        self._measured = False  # the estimator has taken a wattmeter reading (since a reset)
        self._runs_without = 0  # runs in a row without a wattmeter sample

    @property
    def timeouts(self) -> int:
        return self.monitor.timeouts

    def monitors(self) -> dict[str, SensorMonitor]:
        return {"tps": self.monitor}

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("TPS_Sensor", self._on_tps, self.monitor.on_e2e_error),
                Subscription("ETB_Wattmeter", self._on_wattmeter)]

    def _on_tps(self, values: dict[str, float], t_ns: int) -> None:
        self.monitor.on_frame(t_ns, values["TPS_Voltage"])

    def _on_wattmeter(self, values: dict[str, float], t_ns: int) -> None:
        samples = self._samples
        if len(samples) >= MAX_BACKLOG:
            samples.popleft()
            self.samples_dropped += 1
        samples.append((values["ETB_Voltage"], values["ETB_Power"]))

    def run(self, t_ns: int, send: Send) -> None:
        est = self.estimator
        samples = self._samples
        if not samples:
            est.step(self._u_prev, None)  # no new measurement: predict only, with the last u
            self._runs_without += 1
        else:
            self._runs_without = 0
            self._measured = True
        while samples:  # predict with u_{k-1}, update with y_k
            u, y = samples.popleft()
            est.step(self._u_prev, y)
            self._u_prev = u
        theta_hat = est.theta_deg
        std = est.theta_std_deg
        if not (math.isfinite(theta_hat) and math.isfinite(std)):  # last line of defence
            self.estimator_faults += 1
            est.reset()
            theta_hat, std = self.angle, 51.0
            self._measured = False
        angle, source, status = self.monitor.select(t_ns, theta_hat, std)
        self.angle, self.source, self.status = angle, source, status
        self.validity = validity = (INIT if not self._measured else
                                    DEGRADED if self._runs_without >= STALE_RUNS else VALID)
        self.estimates_sent += send(*self._est_frame(
            t_ns / NS_PER_S, 0, self._tx_counter, source, validity, angle, theta_hat, std,
            int(status)))
        self._tx_counter = (self._tx_counter + 1) % self._modulo

    def status_signals(self) -> dict[str, int]:
        return {"ECU_TpsDtc": int(self.monitor.dtc)}

    def dids(self) -> list[Did]:
        """UDS: angles, source, TPS input and status, the TPS plausibility margin (0x2E)."""
        mon, est = self.monitor, self.estimator

        def set_margin(v: float) -> None:
            mon.cfg = replace(mon.cfg, plaus_margin=v)

        return [
            Did(0x0100, "throttle angle (broadcast)", "H", 0.01, "deg", lambda: self.angle),
            Did(0x0101, "throttle angle estimate", "H", 0.01, "deg", lambda: est.theta_deg),
            Did(0x0102, "throttle estimate std", "H", 0.01, "deg", lambda: est.theta_std_deg),
            Did(0x0103, "throttle source (0 sensor, 1 estimate)", "B", 1, "",
                lambda: float(self.source)),
            Did(0x0104, "TPS voltage (last valid)", "H", 0.0001, "V", lambda: mon.raw,
                io=("TPS_Sensor", "TPS_Voltage")),
            Did(0x0105, "TPS status", "B", 1, "", status_reader(mon)),
            Did(0x0110, "TPS plausibility margin (ecu.throttle.tps_monitor.plaus_margin)",
                "H", 0.01, "deg", lambda: mon.cfg.plaus_margin, write=set_margin),
            validity_did(0x010F, "throttle estimate validity", lambda: self.validity),
        ]

    def dtcs(self) -> tuple[DtcSpec, ...]:
        """UDS: the TPS sensor's DTCs."""
        return DTCS

    def calibrations(self) -> Calibrations:
        """Taken mid-run (XCP, timed sets): the TPS monitor's settings."""
        return {"throttle.tps_monitor": self.monitor.recalibrate}

    def variables(self) -> list[Variable]:
        """XCP measurements: estimate, sigma, broadcast, TPS angle, source, resets."""
        est, mon = self.estimator, self.monitor
        return [
            Variable("throttle.estimate_deg", "deg", FLOAT, lambda: est.theta_deg, -10, 100,
                     "throttle angle estimate"),
            Variable("throttle.sigma_deg", "deg", FLOAT, lambda: est.theta_std_deg, 0, 100,
                     "throttle estimate standard deviation"),
            Variable("throttle.angle_deg", "deg", FLOAT, lambda: self.angle, -10, 100,
                     "throttle angle broadcast (sensor or estimate)"),
            Variable("throttle.tps_deg", "deg", FLOAT, lambda: mon.value, -10, 100,
                     "TPS angle as the ECU sees it (last valid frame)"),
            Variable("throttle.source", "1", UBYTE, lambda: self.source, 0, 1,
                     "0 sensor, 1 estimate"),
            Variable("throttle.estimator_resets", "1", ULONG, lambda: est.resets, 0, 4294967295,
                     "estimator resets"),
        ]
