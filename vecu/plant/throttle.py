"""Electronic throttle body: piecewise-affine 3-mode model (Vargas et al. 2015, eq. 3, Table I).

State x = [theta, rho, i]: valve angle theta in degrees (the paper's 0.1 factor dropped, see
docs/models.md), angular velocity rho in the model's own units, motor current i in A.
Input u: terminal voltage in V. Wattmeter measurement y = i**2 + v (eq. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from scipy import signal

from vecu.calibration import TpsCalibration

THETA_MIN_DEG = 0.0
THETA_MAX_DEG = 90.0
MODE_BOUNDS_DEG = (8.0, 16.0)  # Theta_1 = [0, 8], Theta_2 = (8, 16], Theta_3 = (16, 90]
DT_S = 1e-3  # the paper's sampling period
INPUT_CHUNK = 1000  # input samples generated at a time


@dataclass(frozen=True)
class ModeParams:
    """One column of Table I."""

    a12: float
    a21: float
    a22: float
    a23: float
    a32: float
    a33: float
    b: float
    c1: float
    c2: float
    c3: float


TABLE_I: tuple[ModeParams, ModeParams, ModeParams] = (
    ModeParams(-0.003, 0.148, 0.9625, -0.8673, 0.0005, 0.944, 0.0741, -0.0654, -0.007, 0.2255),
    ModeParams(0.0021, -0.143, 0.9941, 1.8944, -0.0004, 0.9514, 0.0346, -0.1068, 0.0529, -0.3419),
    ModeParams(0.0442, -0.0192, 0.7981, 0.3538, 0.0349, 0.9043, 0.0442, -0.0055, 0.0615, -0.0862),
)

# Process-noise gain F = diag(sqrt(0.35), 0, sqrt(0.18)) per 1 ms step (Section III-B).
F_DIAG: tuple[float, float, float] = (math.sqrt(0.35), 0.0, math.sqrt(0.18))
# Wattmeter noise gain H = 1 (eq. 4, v standard Gaussian).
H_WATTMETER = 1.0


def mode_index(theta: float) -> int:
    """Return 0, 1 or 2 for Theta_1, Theta_2, Theta_3 (negative theta counts as Theta_1)."""
    if theta <= MODE_BOUNDS_DEG[0]:
        return 0
    if theta <= MODE_BOUNDS_DEG[1]:
        return 1
    return 2


def _sgn(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


def clip_theta(theta: float) -> float:
    """Mechanical stops: theta in [0, 90] deg (see docs/models.md, 'clip after every step')."""
    if theta < THETA_MIN_DEG:
        return THETA_MIN_DEG
    if theta > THETA_MAX_DEG:
        return THETA_MAX_DEG
    return theta


def step_mean(theta: float, rho: float, i: float, u: float) -> tuple[float, float, float]:
    """Noise-free part of eq. (3): x_{k+1} = A_s x_k + B_s u_k + c_s(x_k), before the clip."""
    p = TABLE_I[mode_index(theta)]
    theta_n = theta + p.a12 * rho
    rho_n = (
        p.a21 * theta + p.a22 * rho + p.a23 * i
        + p.c1 * _sgn(rho) + p.c2 * _sgn(theta - 1.0) + p.c3
    )
    i_n = p.a32 * rho + p.a33 * i + p.b * u
    return theta_n, rho_n, i_n


def wattmeter_mean(i: float) -> float:
    """h(x) of eq. (4): the power reading without noise, i**2."""
    return i * i


@dataclass(frozen=True)
class ThrottlePlantConfig:
    """Plant settings. noise_scale alpha scales F (alpha = 1: the paper's figure)."""

    noise_scale: float = 1.0
    tps_noise_v: float = 0.002  # TPS electrical noise, 1 sigma (V); 0.002 V = 0.036 deg
    block: int = 1_000  # noise rows drawn at a time (the stream does not depend on it)


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
        self._sig_theta = config.noise_scale * F_DIAG[0]
        self._sig_i = config.noise_scale * F_DIAG[2]

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
        theta_n, rho_n, i_n = step_mean(self.theta, self.rho, self.i, u)
        self.theta = clip_theta(theta_n + self._sig_theta * w[0])
        self.rho = rho_n
        self.i = i_n + self._sig_i * w[1]

    def wattmeter(self) -> float:
        """y_k = i_k**2 + v_k (eq. 4), in W (model units)."""
        if self._pos >= len(self._noise):
            self._refill()
        return self.i * self.i + H_WATTMETER * self._noise[self._pos][2]

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


class InputGenerator:
    """Sample-by-sample view of input_blocks()."""

    def __init__(self, config: InputConfig, rng: np.random.Generator) -> None:
        self._blocks = input_blocks(config, rng)
        self._buf: list[float] = []
        self._pos = 0

    def next(self) -> float:
        if self._pos >= len(self._buf):
            self._buf = next(self._blocks)
            self._pos = 0
        u = self._buf[self._pos]
        self._pos += 1
        return u


@dataclass(frozen=True)
class ThrottleTrace:
    """An offline simulation: arrays of length steps (index k = time k ms)."""

    u: np.ndarray
    theta: np.ndarray
    rho: np.ndarray
    i: np.ndarray
    y: np.ndarray


def rng_streams(seed: int, names: tuple[str, ...]) -> dict[str, np.random.Generator]:
    """Independent, named random streams from one seed (adding a stream never shifts another)."""
    out = {}
    for name in names:
        entropy = [seed] + [ord(c) for c in name]
        out[name] = np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))
    return out


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
