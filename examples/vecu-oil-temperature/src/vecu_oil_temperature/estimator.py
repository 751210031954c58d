"""The ECU side: a scalar Kalman filter on the warm-up law (predict with the exact lag, update
with each accepted reading), broadcast as OIL_Estimate with its validity. A reading outside the
calibrated range is refused (counted by the ECU as a value error); no reading for
timeout_cycles periods makes the estimate degraded (the model coasts)."""

from __future__ import annotations

import math

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.diagnostics import FLOAT, UBYTE, Calibrations, Did, Variable, validity_did
from vecu.ecu.node import Send, Subscription
from vecu.ecu.validity import DEGRADED, INIT, VALID
from vecu_oil_temperature.model import OilTemperatureConfig

PERIOD_NS = 100 * NS_PER_MS


class OilTemperatureFunction:
    """A vecu EcuFunction (vecu.ecu.node): name, period_ns, timeouts, subscriptions, run,
    status_signals, dids, variables, calibrations."""

    name = "oil_temperature"
    period_ns = PERIOD_NS

    def __init__(self, config: OilTemperatureConfig, codec: DbcCodec) -> None:
        self.config = config
        self._out = codec["OIL_Estimate"]
        self.estimate: float | None = None
        self.variance = 0.0
        self.validity = INIT
        self.timeouts = 0
        self.estimates_sent = 0
        self._reading: float | None = None
        self._last_ns: int | None = None
        self._last_reading_ns = 0

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("OIL_Sensor", self._on_sensor)]

    def _on_sensor(self, values: dict[str, float], t_ns: int) -> str | None:
        temp = values["OIL_Temp"]
        if not self.config.low_degc <= temp <= self.config.high_degc:
            return f"oil temperature {temp:.1f} degC outside the calibrated range"
        self._reading, self._last_reading_ns = temp, t_ns
        return None

    def run(self, t_ns: int, send: Send) -> None:
        cfg = self.config
        if self.estimate is None:
            if self._reading is None:
                return
            self.estimate, self.variance = self._reading, cfg.r_degc2  # first reading
        else:
            dt = (t_ns - (self._last_ns or t_ns)) / NS_PER_S
            a = math.exp(-dt / cfg.model.tau_s)
            self.estimate = cfg.model.advance(self.estimate, dt)  # predict
            self.variance = a * a * self.variance + cfg.q_degc2_per_s * dt
        self._last_ns = t_ns
        if self._reading is not None:  # update
            gain = self.variance / (self.variance + cfg.r_degc2)
            self.estimate += gain * (self._reading - self.estimate)
            self.variance *= 1.0 - gain
            self._reading = None
        silent = t_ns - self._last_reading_ns > cfg.timeout_cycles * PERIOD_NS
        if silent and self.validity != DEGRADED:
            self.timeouts += 1
        self.validity = DEGRADED if silent else VALID
        self.estimates_sent += send(self._out.frame(
            {"OIL_TempEst": self.estimate, "OIL_TempEstStd": math.sqrt(self.variance),
             "OIL_Validity": self.validity}, t_ns / NS_PER_S))

    def status_signals(self) -> dict[str, int]:
        return {}

    def dids(self) -> list[Did]:
        return [Did(0x0700, "oil temperature estimate", "h", 0.1, "degC", lambda: self.estimate),
                validity_did(0x070F, "oil temperature validity", lambda: self.validity)]

    def variables(self) -> list[Variable]:
        return [Variable("oil_temperature.estimate_degc", "degC", FLOAT, lambda: self.estimate,
                         -50, 200, "oil temperature estimate"),
                Variable("oil_temperature.validity", "", UBYTE, lambda: self.validity, 0, 3,
                         "oil temperature validity")]

    def calibrations(self) -> Calibrations:
        """Its whole subtree is live: a new calibration acts from the next run."""
        return {"oil_temperature": self._recalibrate}

    def _recalibrate(self, config: OilTemperatureConfig) -> None:
        self.config = config
