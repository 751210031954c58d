"""Virtual ECU node: receive and validate frames, run the throttle estimator, broadcast estimates.

Every tick (1 ms): drain the receive queue (each frame is checked for kind, known ID, DLC, E2E CRC
and alive counter, NaN / out-of-range values, and counted when rejected), step the estimator from
the wattmeter and commanded voltage only (hot standby), diagnose the TPS, and send
ECU_ThrottleEstimate with the sensor angle while the TPS is healthy and the estimate otherwise.
ECU_Status goes out at its DBC cycle time. Nothing a frame contains can raise out of tick().
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field

import can

from vecu.calibration import TpsCalibration
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec, FrameCodec
from vecu.e2e import AliveCounterCheck
from vecu.ecu.tps_monitor import TpsMonitor, TpsMonitorConfig, TpsStatus
from vecu.estimators.base import ThrottleEstimator
from vecu.node import BusNode

log = logging.getLogger(__name__)

SOURCE_SENSOR, SOURCE_ESTIMATE = 0, 1
MAX_LOGGED_PER_KIND = 20  # rx problems logged individually before going quiet (still counted)


@dataclass
class RxCounters:
    """Receive statistics; every frame lands in exactly one of accepted / ignored / a reject bin."""

    received: int = 0
    accepted: int = 0
    ignored: int = 0           # known IDs this ECU does not consume (incl. own echoed frames)
    unknown_id: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    dlc_errors: int = 0
    crc_errors: int = 0
    counter_errors: int = 0
    value_errors: int = 0      # NaN / inf / outside the DBC range
    malformed: int = 0         # anything else the decoder refused
    timeouts: int = 0          # confirmed TPS timeouts

    @property
    def rejected(self) -> int:
        return (self.unknown_id + self.error_frames + self.remote_frames + self.dlc_errors
                + self.crc_errors + self.counter_errors + self.value_errors + self.malformed)

    def as_dict(self) -> dict[str, int]:
        return {**asdict(self), "rejected": self.rejected}


@dataclass(frozen=True)
class EcuConfig:
    tps_monitor: TpsMonitorConfig = field(default_factory=TpsMonitorConfig)
    calibration: TpsCalibration = field(default_factory=TpsCalibration)


class EcuNode(BusNode):
    """The virtual ECU; call tick(t_ns) from a 1 ms scheduler task."""

    def __init__(self, bus: can.BusABC, codec: DbcCodec, estimator: ThrottleEstimator,
                 config: EcuConfig = EcuConfig()) -> None:
        super().__init__(bus, "ecu")
        self.codec = codec
        self.estimator = estimator
        self.rx = RxCounters()
        self.estimates_sent = 0  # ECU_ThrottleEstimate frames on the bus (one per tick if healthy)
        self.overruns = 0  # set by the runner from the scheduler's count
        self.estimator_faults = 0  # non-finite estimator outputs caught here (should stay 0)
        self._tps = codec["TPS_Sensor"]
        self._watt = codec["ETB_Wattmeter"]
        self._est = codec["ECU_ThrottleEstimate"]
        self._status = codec["ECU_Status"]
        tps_cycle = self._tps.cycle_time_ms or config.tps_monitor.cycle_ms
        monitor_cfg = config.tps_monitor
        if monitor_cfg.cycle_ms != tps_cycle:
            monitor_cfg = TpsMonitorConfig(**{**asdict(monitor_cfg), "cycle_ms": tps_cycle})
        self.monitor = TpsMonitor(monitor_cfg, config.calibration)
        self._tps_counter = AliveCounterCheck()
        self._consumers = {
            (self._tps.frame_id, self._tps.is_extended): self._on_tps,
            (self._watt.frame_id, self._watt.is_extended): self._on_wattmeter,
        }
        self._status_period_ns = int((self._status.cycle_time_ms or 100) * NS_PER_MS)
        self._next_status_ns = 0
        self._tx_counter = 0
        self._status_counter = 0
        self._logged: dict[str, int] = {}
        self._u_now = 0.0
        self._u_prev = 0.0
        self._y: float | None = None
        # last broadcast, read by probes
        self.angle = 0.0
        self.source = SOURCE_SENSOR
        self.status = TpsStatus.OK

    # ---------------------------------------------------------------- receive
    def _problem(self, kind: str, msg: can.Message, detail: str = "") -> None:
        n = self._logged.get(kind, 0) + 1
        self._logged[kind] = n
        if n <= MAX_LOGGED_PER_KIND:
            log.warning("ecu rx %s: id=0x%X dlc=%d data=%s %s%s", kind, msg.arbitration_id,
                        msg.dlc, bytes(msg.data).hex(), detail,
                        " (further ones counted, not logged)" if n == MAX_LOGGED_PER_KIND else "")

    def receive(self, msg: can.Message, t_ns: int) -> None:
        """Validate one frame and hand it to its consumer; never raises."""
        rx = self.rx
        rx.received += 1
        try:
            if msg.is_error_frame:
                rx.error_frames += 1
                self._problem("error-frame", msg)
                return
            key = (msg.arbitration_id, msg.is_extended_id)
            consumer = self._consumers.get(key)
            if consumer is None:
                if key in self.codec.by_id:
                    rx.ignored += 1
                else:
                    rx.unknown_id += 1
                    self._problem("unknown-id", msg)
                return
            if msg.is_remote_frame:
                rx.remote_frames += 1
                self._problem("remote-frame", msg)
                return
            consumer(msg, t_ns)
        except Exception as exc:  # a decoder bug must not stop the ECU
            rx.malformed += 1
            self._problem("malformed", msg, f"{type(exc).__name__}: {exc}")

    def _checked_values(self, codec: FrameCodec, msg: can.Message) -> dict[str, float] | None:
        rx = self.rx
        data = msg.data
        if len(data) != codec.length:
            rx.dlc_errors += 1
            self._problem("dlc", msg, f"expected {codec.length} bytes")
            return None
        if codec.e2e is not None and not codec.crc_ok(data):
            rx.crc_errors += 1
            self._problem("crc", msg)
            return None
        values = codec.decode(data)
        bad = codec.bad_values(values)
        if bad:
            rx.value_errors += 1
            self._problem("value", msg, f"bad {', '.join(bad)}")
            return None
        return values

    def _on_tps(self, msg: can.Message, t_ns: int) -> None:
        values = self._checked_values(self._tps, msg)
        if values is None:
            if self._tps.crc_ok(msg.data) is False and len(msg.data) == self._tps.length:
                self.monitor.on_e2e_error()
            return
        if not self._tps_counter.check(int(values["TPS_AliveCounter"])):
            self.rx.counter_errors += 1
            self._problem("alive-counter", msg)
            self.monitor.on_e2e_error()
            return
        self.rx.accepted += 1
        self.monitor.on_frame(t_ns, values["TPS_Voltage"])

    def _on_wattmeter(self, msg: can.Message, t_ns: int) -> None:
        values = self._checked_values(self._watt, msg)
        if values is None:
            return
        self.rx.accepted += 1
        self._u_now = values["ETB_Voltage"]
        self._y = values["ETB_Power"]

    # ------------------------------------------------------------------- tick
    def tick(self, t_ns: int) -> None:
        recv = self.bus.recv
        while (msg := recv(0.0)) is not None:
            self.receive(msg, t_ns)
        est = self.estimator
        est.step(self._u_prev, self._y)  # predict with u_{k-1}, update with y_k (or predict only)
        self._u_prev = self._u_now
        self._y = None
        theta_hat = est.theta_deg
        std = est.theta_std_deg
        if not (math.isfinite(theta_hat) and math.isfinite(std)):  # last line of defence
            self.estimator_faults += 1
            est.reset()
            theta_hat, std = self.angle, 51.0
        was_ok = self.monitor.healthy
        status = self.monitor.evaluate(t_ns, theta_hat, std)
        if was_ok and status == TpsStatus.TIMEOUT:
            self.rx.timeouts += 1
        sensor = self.monitor.angle
        if status == TpsStatus.OK and sensor is not None:
            angle, source = sensor, SOURCE_SENSOR
        else:
            angle, source = theta_hat, SOURCE_ESTIMATE
        self.angle, self.source, self.status = angle, source, status
        ts = t_ns / NS_PER_S
        self.estimates_sent += self._send(self._est.frame({
            "THR_CRC": 0, "THR_AliveCounter": self._tx_counter, "THR_Source": source,
            "THR_Angle": angle, "THR_AngleEst": theta_hat,
            "THR_AngleEstStd": min(std, 51.0), "THR_TpsStatus": int(status),
        }, ts))
        self._tx_counter = (self._tx_counter + 1) & 0xF
        if t_ns >= self._next_status_ns:
            self._next_status_ns += self._status_period_ns
            self._send_status(ts)

    def _send_status(self, ts: float) -> None:
        rx = self.rx
        sat8 = lambda v: min(v, 255)  # noqa: E731 - DBC counters saturate
        self._send(self._status.frame({
            "ECU_StatusCounter": self._status_counter, "ECU_TpsDtc": int(self.monitor.dtc),
            "ECU_Overruns": min(self.overruns, 65535),
            "ECU_RxDlcErrors": sat8(rx.dlc_errors),
            "ECU_RxE2EErrors": sat8(rx.crc_errors + rx.counter_errors),
            "ECU_RxValueErrors": sat8(rx.value_errors + rx.malformed),
            "ECU_RxUnknownIds": sat8(rx.unknown_id), "ECU_RxTimeouts": sat8(rx.timeouts),
        }, ts))
        self._status_counter = (self._status_counter + 1) & 0xF
