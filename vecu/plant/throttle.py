"""Electronic throttle body simulator (Vargas 2015): stochastic eq. (3) (`plant_step`), the ticks
as one kernel (`advance_ticks`), the Section III-B excitation, the offline `simulate` and
`ThrottlePart`, which sends the sensor frames. The model itself is vecu.models.throttle.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from vecu.can_message import message
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.faults import FaultInjector, FaultTarget
from vecu.kernels import kernel
from vecu.models.sensors import TpsCalibration, tps_law
from vecu.models.throttle import (
    PAPER_THROTTLE,
    ThrottleModel,
    clip_theta,
    eq3_step,
    wattmeter_reading,
)
from vecu.plant.input_file import BufferedInput
from vecu.plant.part import Send, payload_rows
from vecu.rng import rng_streams

INPUT_CHUNK = 1000  # input samples generated at a time


@dataclass(frozen=True)
class ThrottlePlantConfig:
    """Plant settings. noise_scale alpha scales F (alpha = 1: the paper's figure)."""

    noise_scale: float = 1.0
    tps_noise_v: float = 0.002  # TPS electrical noise, 1 sigma (V); 0.002 V = 0.036 deg
    model: ThrottleModel = PAPER_THROTTLE  # Table I, mode bounds, F and H of this throttle body
    # noise rows drawn at a time (the stream does not depend on it): not a parameter of the car
    block: int = field(default=1_000, metadata={"param": False})


@kernel
def plant_step(rows: Any, b1: float, b2: float, sig_theta: float, sig_i: float, theta: float,
               rho: float, i: float, u: float, w_theta: float, w_i: float
               ) -> tuple[float, float, float]:
    """x_{k+1} = f(x_k, u_k) + F w_k (eq. 3, F = diag(sig_theta, 0, sig_i)), theta clipped to
    the stops [0, 90] deg after the noise."""
    theta_n, rho_n, i_n = eq3_step(rows, b1, b2, theta, rho, i, u)
    return clip_theta(theta_n + sig_theta * w_theta), rho_n, i_n + sig_i * w_i


@kernel
def advance_ticks(st, u, noise, pos, rows, b1, b2, sig_theta, sig_i, h, tps_noise, v_at_0,
                  v_at_90, out):
    """Ticks k = 0.. of u: out[k] = (theta_k, rho_k, i_k, y_k = i_k^2 + H v_k (eq. 4), the TPS
    voltage) on x_k, then plant_step; st = (theta, rho, i) is advanced in place, the noise rows
    (w_theta, w_i, v, TPS noise) taken from pos on; rows: the 3x10 mode rows. Stops when u, out
    or the noise rows run out; returns (ticks, the next noise row)."""
    theta, rho, i = st[0], st[1], st[2]
    k = 0
    while k < len(u) and k < len(out) and pos < len(noise):
        w = noise[pos]
        out[k, 0] = theta
        out[k, 1] = rho
        out[k, 2] = i
        out[k, 3] = wattmeter_reading(i, h, w[2])
        out[k, 4] = tps_law(v_at_0, v_at_90, theta) + tps_noise * w[3]
        theta, rho, i = plant_step(rows, b1, b2, sig_theta, sig_i, theta, rho, i, u[k], w[0],
                                   w[1])
        pos += 1
        k += 1
    st[0], st[1], st[2] = theta, rho, i
    return k, pos


class ThrottlePlant:
    """Stochastic eq. (3), a block of ticks per advance_ticks call; the noise drawn in fixed-size
    blocks (the stream does not depend on how many ticks a call takes)."""

    def __init__(self, config: ThrottlePlantConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self.state = np.zeros(3)  # (theta, rho, i) of the next tick
        self._noise = np.empty((0, 4))
        self._pos = 0
        model = config.model
        self._rows = np.array(model.rows, dtype=np.float64)
        self._b1, self._b2 = (float(b) for b in model.mode_bounds_deg)
        self._sig_theta = config.noise_scale * model.f_diag[0]
        self._sig_i = config.noise_scale * model.f_diag[2]

    def ticks(self, u: list[float] | np.ndarray,
              calibration: TpsCalibration = TpsCalibration()) -> np.ndarray:
        """(len(u), 5) rows (theta, rho, i, y, TPS voltage) of the next ticks with inputs u: each
        row measured on x_k, then x_{k+1} = f(x_k, u_k) + F w_k."""
        ua = np.array(u, dtype=np.float64)
        out = np.empty((len(ua), 5))
        done = 0
        while done < len(ua):
            if self._pos >= len(self._noise):
                self._noise = self._rng.standard_normal((self.config.block, 4))
                self._pos = 0
            k, self._pos = advance_ticks(
                self.state, ua[done:], self._noise, self._pos, self._rows, self._b1, self._b2,
                self._sig_theta, self._sig_i, self.config.model.h_wattmeter,
                self.config.tps_noise_v, calibration.v_at_0, calibration.v_at_90, out[done:])
            done += k
        return out


@dataclass(frozen=True)
class InputConfig:
    """Excitation of Section III-B: random pulses through a 4th-order Butterworth low-pass."""

    pulse_min_ms: int = 20
    pulse_max_ms: int = 2000
    u_max_v: float = 10.0
    cutoff_min_hz: float = 0.01
    cutoff_max_hz: float = 60.0
    cutoff_period_ms: int = 10_000  # cutoff redrawn every 10 s
    fs_hz: float = 1000.0


def input_blocks(config: InputConfig, rng: np.random.Generator) -> Iterator[list[float]]:
    """Successive chunks of u (V), clipped to [0, u_max]: the cutoff redrawn every period, the
    filter (second-order sections, stable at 0.01 Hz) carried across chunks, so u is continuous."""
    zi = None
    level = 0.0
    remaining = 0
    period = config.cutoff_period_ms
    while True:
        cutoff = rng.uniform(config.cutoff_min_hz, config.cutoff_max_hz)
        sos = signal.butter(4, cutoff, btype="low", fs=config.fs_hz, output="sos")
        done = 0
        while done < period:
            n = min(INPUT_CHUNK, period - done)
            raw = np.empty(n)
            k = 0
            while k < n:
                if remaining == 0:
                    remaining = int(rng.integers(config.pulse_min_ms, config.pulse_max_ms + 1))
                    level = float(rng.uniform(0.0, config.u_max_v))
                take = min(remaining, n - k)
                raw[k:k + take] = level
                k += take
                remaining -= take
            if zi is None:
                zi = signal.sosfilt_zi(sos) * raw[0]
            filtered, zi = signal.sosfilt(sos, raw, zi=zi)
            done += n
            yield np.clip(filtered, 0.0, config.u_max_v).tolist()


class InputGenerator(BufferedInput):
    """Sample-by-sample (or many at a time) view of input_blocks()."""

    def __init__(self, config: InputConfig, rng: np.random.Generator) -> None:
        self._blocks = input_blocks(config, rng)
        self._buf: list[float] = []
        self._pos = 0

    def _refill(self) -> list[float]:
        return next(self._blocks)


@dataclass(frozen=True)
class ThrottleTrace:
    """An offline simulation: arrays of length steps (index k = time k ms)."""

    u: np.ndarray
    theta: np.ndarray
    rho: np.ndarray
    i: np.ndarray
    y: np.ndarray


def simulate(steps: int, seed: int = 0, noise_scale: float = 1.0) -> ThrottleTrace:
    """Run the plant offline: u_k, then y_k measured on x_k, then x_{k+1} = f(x_k, u_k) + F w_k."""
    rngs = rng_streams(seed, ("throttle.input", "throttle.plant"))
    u = np.array(InputGenerator(InputConfig(), rngs["throttle.input"]).take(steps))
    plant = ThrottlePlant(ThrottlePlantConfig(noise_scale=noise_scale), rngs["throttle.plant"])
    theta, rho, i, y = (np.ascontiguousarray(c) for c in plant.ticks(u).T[:4])
    return ThrottleTrace(u=u, theta=theta, rho=rho, i=i, y=y)


# --------------------------------------------------------------------------- on the bus
_TPS = FaultTarget.TPS  # bound once (per-tick code)
TPS_V_MIN, TPS_V_MAX = 0.0, 5.0  # sensor output saturates at ground and supply
TPS_SIGNALS = ("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage")
WATT_SIGNALS = ("ETB_Voltage", "ETB_Power")


class ThrottlePart:
    """Throttle body (Vargas 2015): TPS_Sensor (E2E) and ETB_Wattmeter every 1 ms, measured on
    x_k, faults applied, then x_{k+1} by eq. (3). Ticks are computed AHEAD at a time (the plant
    depends on nothing the ECU sends) and framed in blocks; a tick whose TPS frame differs from
    the block's (a fault, a counter moved on) is framed on its own."""

    truth_message = "TRUTH_Throttle"  # its truth frame (dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "throttle"
    period_ns = NS_PER_MS
    AHEAD = 500  # ticks per ThrottlePlant.ticks call

    def __init__(self, codec: DbcCodec, plant: ThrottlePlant, inputs: BufferedInput,
                 injector: FaultInjector, calibration: TpsCalibration = TpsCalibration()) -> None:
        self.plant = plant
        self.inputs = inputs
        self.injector = injector
        self.calibration = calibration
        self._tps = codec["TPS_Sensor"]
        self._watt = codec["ETB_Wattmeter"]
        self._tps_frame = self._tps.framer(TPS_SIGNALS)
        e2e = self._tps.e2e
        assert e2e is not None, "TPS_Sensor is E2E-protected in vecu.dbc"
        self._modulo = e2e.protection.counter_modulo  # P11: 0..14
        self._watt_frame = self._watt.framer(WATT_SIGNALS)
        self._counter = 0
        self.truth_msg = None  # TRUTH_Throttle codec when recording truth (PlantNode.enable_truth)
        # truth and sensor of the last tick, read by probes
        self.theta = 0.0
        self.u = 0.0
        self.tps_voltage: float | None = None
        # the ticks ahead: inputs, (theta, y, TPS voltage) rows, their frames' payloads (None:
        # left to the framer), the TPS counter the first of them was encoded with
        self._us: list[float] = []
        self._rows: list[list[float]] = []
        self._tps_ahead: list[bytearray | None] = []
        self._watt_ahead: list[bytearray | None] = []
        self._counter_ahead = 0
        self._k = 0

    def _fill(self) -> None:
        """The next AHEAD ticks: their rows and the payloads of their frames."""
        self._us = us = self.inputs.take(self.AHEAD)
        cols = self.plant.ticks(us, self.calibration).T
        self._rows = np.stack((cols[0], cols[3], cols[4]), axis=1).tolist()
        n = len(us)
        v = np.where(cols[4] < TPS_V_MIN, TPS_V_MIN, np.minimum(cols[4], TPS_V_MAX))
        self._counter_ahead = c0 = self._counter
        self._tps_ahead = payload_rows(self._tps.encode_rows(TPS_SIGNALS, (
            np.zeros(n), (c0 + np.arange(n)) % self._modulo, v)), n)
        self._watt_ahead = payload_rows(self._watt.encode_rows(WATT_SIGNALS, (
            np.array(us), cols[3])), n)
        self._k = 0

    def tick(self, t_ns: int, send: Send) -> None:
        if self._k >= len(self._rows):
            self._fill()
        k = self._k
        self._k = k + 1
        u = self._us[k]
        theta, y, v_sensor = self._rows[k]
        v = self.injector.apply(_TPS, v_sensor)
        ts = t_ns / NS_PER_S
        if v is not None:
            data = (self._tps_ahead[k] if v == v_sensor
                    and self._counter == (self._counter_ahead + k) % self._modulo else None)
            v = TPS_V_MIN if v < TPS_V_MIN else (min(v, TPS_V_MAX))
            if data is not None:  # encoded from the same clamped voltage and counter
                send(message(ts, self._tps.frame_id, self._tps.is_extended, data, self._tps.is_fd))
            else:
                send(self._tps_frame(ts, 0, self._counter, v)[0])
            self._counter = (self._counter + 1) % self._modulo
        data = self._watt_ahead[k]
        if data is not None:
            send(message(ts, self._watt.frame_id, self._watt.is_extended, data, self._watt.is_fd))
        else:
            send(self._watt_frame(ts, u, y)[0])
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_ThrottleAngle": theta, "TRU_MotorVoltage": u}, ts))
        self.theta = theta
        self.u = u
        self.tps_voltage = v
