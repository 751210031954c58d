"""Electronic throttle body simulator: stochastic eq. (3) and the Section III-B excitation.

The model itself (Table I, eq. 3-4) is vecu.models.throttle and one step with noise
vecu.plant.throttle_kernel.plant_step; this module adds state, the noise stream, the TPS sensor
and the input generator.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from vecu.models.sensors import TpsCalibration
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel, wattmeter_reading
from vecu.plant.input_file import BufferedInput
from vecu.plant.throttle_kernel import advance_ticks, plant_step
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


class ThrottlePlant:
    """Stochastic eq. (3) with theta clipped to the stops; noise drawn in fixed-size blocks."""

    def __init__(self, config: ThrottlePlantConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self.theta = 0.0
        self.rho = 0.0
        self.i = 0.0
        self._noise: list[list[float]] = []
        self._pos = 0
        self._sig_theta = config.noise_scale * config.model.f_diag[0]
        self._sig_i = config.noise_scale * config.model.f_diag[2]
        self._rows = config.model.rows
        self._b1, self._b2 = (float(b) for b in config.model.mode_bounds_deg)
        self._h = config.model.h_wattmeter

    def _refill(self) -> None:
        block = self._rng.standard_normal((self.config.block, 4))
        self._noise = block.tolist()
        self._pos = 0

    def step(self, u: float) -> None:
        """Advance one 1 ms step with input u (V)."""
        if self._pos >= len(self._noise):
            self._refill()
        w = self._noise[self._pos]
        self._pos += 1
        self.theta, self.rho, self.i = plant_step.py(
            self._rows, self._b1, self._b2, self._sig_theta, self._sig_i, self.theta, self.rho,
            self.i, u, w[0], w[1])

    def wattmeter(self) -> float:
        """y_k = i_k**2 + v_k (eq. 4), in W (model units)."""
        if self._pos >= len(self._noise):
            self._refill()
        return wattmeter_reading.py(self.i, self._h, self._noise[self._pos][2])

    def tps_voltage(self, calibration: TpsCalibration) -> float:
        """Position-sensor output for the current angle, with small electrical noise."""
        if self._pos >= len(self._noise):
            self._refill()
        return calibration.voltage(self.theta) + self.config.tps_noise_v * self._noise[self._pos][3]


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
    """Yield successive chunks of u (V), clipped to [0, u_max].

    The cutoff is redrawn every cutoff period; second-order sections keep the 0.01 Hz filter
    stable at 1 kHz, and the filter state is carried across chunks and cutoff changes, so u is
    continuous. Chunks are short (INPUT_CHUNK samples) so that live runs never stall on one.
    """
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
    gen = InputGenerator(InputConfig(), rngs["throttle.input"])
    plant = ThrottlePlant(ThrottlePlantConfig(noise_scale=noise_scale), rngs["throttle.plant"])
    u = np.empty(steps)
    th = np.empty(steps)
    rh = np.empty(steps)
    cur = np.empty(steps)
    y = np.empty(steps)
    for k in range(steps):
        uk = gen.next()
        u[k] = uk
        th[k] = plant.theta
        rh[k] = plant.rho
        cur[k] = plant.i
        y[k] = plant.wattmeter()
        plant.step(uk)
    return ThrottleTrace(u=u, theta=th, rho=rh, i=cur, y=y)


class TicksAhead:
    """ThrottlePlant's ticks computed ahead in blocks by one compiled call
    (throttle_kernel.advance_ticks), for vecu.plant.node.ThrottlePart under the numba backend:
    the plant's state and noise stream carried on, so the same numbers as stepping it."""

    AHEAD = 500  # ticks per compiled call

    def __init__(self, plant: ThrottlePlant, calibration: TpsCalibration) -> None:
        cfg = plant.config
        model = cfg.model
        self._plant = plant
        self.state = np.array([plant.theta, plant.rho, plant.i], dtype=np.float64)
        self._modes = np.array(model.rows, dtype=np.float64)
        self._cst = np.array([plant._sig_theta, plant._sig_i, model.h_wattmeter, cfg.tps_noise_v,
                              calibration.v_at_0, calibration.v_at_90, *model.mode_bounds_deg],
                             dtype=np.float64)
        self._noise = np.array(plant._noise, dtype=np.float64).reshape(-1, 4)
        self._pos = plant._pos
        self._out = np.empty((self.AHEAD, 3))

    def fill(self, u: list[float]) -> np.ndarray:
        """(len(u), 3) rows (theta, y, TPS voltage) of the next len(u) <= AHEAD ticks with
        inputs u (a view, valid until the next fill)."""
        ua = np.array(u, dtype=np.float64)
        done = 0
        while done < len(ua):
            if self._pos >= len(self._noise):
                self._noise = self._plant._rng.standard_normal((self._plant.config.block, 4))
                self._pos = 0
            k, self._pos = advance_ticks.compiled(self.state, ua[done:], self._noise, self._pos,
                                                  self._modes, self._cst, self._out[done:])
            done += k
        return self._out[:done]
