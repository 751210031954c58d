"""The production throttle-angle estimator: particle filter + Kalman stretches on eq. (3) /
eq. (4) of Vargas et al. 2015, theta in deg clipped to [0, 90] (docs/models.md, "Production
throttle estimator"). A tick is one pf.recursion.filter_tick call on the state record
(pf.state); the rare outcomes it flags are finished here.
"""

from __future__ import annotations

import math

import numpy as np

from vecu.estimators.throttle.pf import kalman_stretch as ks
from vecu.estimators.throttle.pf import model as md
from vecu.estimators.throttle.pf import recursion as rc
from vecu.estimators.throttle.pf.resample import pf_resample
from vecu.estimators.throttle.pf.state import Bank, Frame, new_state
from vecu.estimators.throttle.pf.update import StepWork, frame_moments, set_step_constants
from vecu.models.throttle import PAPER_THROTTLE, THETA_MAX_DEG, THETA_MIN_DEG, ThrottleModel

DEFAULT_N_HIGH = 300
DEFAULT_N_LOW = 600
N_LOW_NOISY = 800  # make_production_estimator: n_low for alpha > NOISY_ALPHA
NOISY_ALPHA = 0.65
LOW_ENTER_DEG = 22.0  # some particle below this: use n_low particles
LOW_EXIT_DEG = 30.0  # all particles above this: back to n_high
# (22 and 30 deg for Table I's mode-3 bound b2 = 16 deg: a calibration with another b2 shifts
# LOW_ENTER / LOW_EXIT and the KF_ENTER / KF_EXIT angles below by b2 - 16)
DEFAULT_SEED = 20150923
NORMAL_TABLE = 1 << 17  # standard normals drawn once; each step reads windows at random offsets
KF_ENTER = (30.0, 85.0, 1.0)  # all particles: theta in (30, 85) deg, i > 1 A -> Kalman filter
# Kalman theta - 3 sigma < 22 deg, theta + 2 sigma > 90 deg (too much mass at the stop) or
# i - 3 sigma < 0.5 A -> particles again
KF_EXIT = (22.0, 2.0, 0.5)
KF_CHECK_EVERY = 8  # steps between checks of the KF_ENTER condition
KF_STEADY_SD_PER_ALPHA = 5.9  # measured steady-state Kalman theta std in mode 3, per unit alpha
KF_GATE = 49.0  # Kalman innovation outlier gate (r^2 / S, 7 sigma)
DEFAULT_STD_INFLATION = 1.2  # theta_std_deg = 1.2 x posterior std (calibration, docs/models.md)
# Stuck below the mode-3 bound (docs/models.md "Consistency"): at or below b2 + LOCK_MARGIN_DEG
# with u > LOCK_U_V the particles can stay parked below b2 after a mode-2 -> mode-3 throw of the
# truth; there the reported variance gets LOCK_STD_DEG^2 added (NEES ~1; the estimate is kept).
LOCK_U_V = 3.0
LOCK_MARGIN_DEG = 1.5
LOCK_STD_DEG = 12.0


class ThrottleParticleFilter:
    """ThrottleEstimator: step(u_prev, y) predicts with eq. (3), updates with y (eq. 4) unless
    missing, implausible or an isolated outlier. Counters: resets, rejected, resamples, resizes,
    kalman_steps, careful_updates. All randomness from PCG64(seed); reset() replays it."""

    def __init__(
        self, noise_scale: float = 1.0, n_high: int = DEFAULT_N_HIGH,
        n_low: int = DEFAULT_N_LOW, seed: int = DEFAULT_SEED,
        std_inflation: float = DEFAULT_STD_INFLATION, init: str = "rest",
        use_kalman: bool = True, model: ThrottleModel = PAPER_THROTTLE,
        lock_std_deg: float = LOCK_STD_DEG,
    ) -> None:
        if min(n_high, n_low) < 8:
            raise ValueError("particle counts must be >= 8")
        if init not in ("rest", "broad"):
            raise ValueError("init must be 'rest' or 'broad'")
        self.name = "production"
        self.noise_scale = a = float(noise_scale)
        self.seed = int(seed)
        self.std_inflation = float(std_inflation)
        self.init = init
        self.use_kalman = bool(use_kalman)
        self.model = model
        f_diag = model.f_diag
        self._s_th = max(a * f_diag[0], 1e-3)
        self._s_i = s_i = max(a * f_diag[2], 1e-3)  # prior std of the current's step noise
        self._cb = cb = md.class_bounds(model)
        shift = cb[2] - md.CLASS_BOUNDS_DEG[2]  # the angle thresholds follow the mode-3 bound
        self._n_high, self._n_low = int(n_high), int(n_low)
        self._S, s = new_state()
        self._s = s  # the named state (pf.state.STATE), a view of _S
        set_step_constants(s, s_i, md.class_b(model), model.h_wattmeter * model.h_wattmeter, cb)
        s.low_enter, s.low_exit = LOW_ENTER_DEG + shift, LOW_EXIT_DEG + shift
        s.kf_enter[:] = (KF_ENTER[0] + shift, *KF_ENTER[1:])
        s.n_low, s.n_high = self._n_low, self._n_high
        s.inflation = self.std_inflation
        s.use_kf, s.kf_every = float(self.use_kalman), KF_CHECK_EVERY
        s.lock_below, s.lock_u = cb[2] + LOCK_MARGIN_DEG, LOCK_U_V
        s.lock_var = float(lock_std_deg) ** 2  # 0: the posterior's std alone
        ks.set_constants(s, self._s_th ** 2, s_i * s_i, model, KF_GATE)
        s.kf_cfg[:] = (KF_EXIT[0] + shift, *KF_EXIT[1:], self.std_inflation)
        self._mats = md.class_matrix_stack(model)
        self._banks = {n: Bank(n, s) for n in {self._n_high, self._n_low}}
        self._work = [StepWork(b.FB, self._mats, s) for b in self._banks.values()]
        self.resets = self.rejected = self.resamples = self.resizes = self.careful_updates = 0
        self.reset()

    steps = property(lambda self: int(self._s.steps))
    kalman_steps = property(lambda self: int(self._s.ksteps))

    @property
    def theta_deg(self) -> float:
        """Posterior mean of theta (deg): the filtered estimate at the last step."""
        return self._theta

    @property
    def theta_std_deg(self) -> float:
        """Posterior std of theta (deg) x std_inflation, floored at 0.3, with LOCK_STD_DEG
        added in quadrature while stuck-prone (theta below b2 + 1.5 deg with u > 3 V), capped
        at 51."""
        return self._std

    @property
    def n_particles(self) -> int:
        """Particles in use (0 during a Kalman stretch)."""
        return 0 if self._s.in_kf else self._b.n

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial prior ('rest': theta=|N(0,1)|, rho, i ~ N(0,1)) and the seed."""
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        self._normals = z = self._rng.standard_normal(NORMAL_TABLE + max(self._banks))
        # rows read by the step: theta process noise, current process noise (prior draw),
        # proposal noise (x sqrt(.5/S) in the step)
        self._ztab = np.empty((3, z.size))
        np.multiply(z, self._s_th, out=self._ztab[0])
        np.multiply(z, self._s_i, out=self._ztab[1])
        np.multiply(z, self._s_i * math.sqrt(2.0), out=self._ztab[2])
        s = self._s
        s.koff = s.offs.size  # none left: the first tick draws them
        s.gated = s.in_kf = 0.0
        self._fill(self.init, None)

    def _fill(self, kind: str, y: float | None) -> None:
        b = self._banks[self._n_low if kind == "broad" else self._n_high]
        f, n, rng = b.cur, b.n, self._rng
        if kind == "rest":
            f.th[:] = np.abs(rng.standard_normal(n))
            f.rh[:] = rng.standard_normal(n)
            f.ci[:] = rng.standard_normal(n)
        else:  # unknown state: any angle, wide rho, |i| from y when it is informative
            f.th[:] = rng.uniform(THETA_MIN_DEG, THETA_MAX_DEG, n)
            f.rh[:] = rng.standard_normal(n) * np.where(f.th > self._cb[-1], 5.0, 60.0)
            r = math.sqrt(y) if y is not None and y > 1.0 else 0.0
            f.ci[:] = np.where(rng.random(n) < 0.85, r, -r) + rng.standard_normal(n)
        f.w.fill(1.0)
        self._b = b
        self._adopt(f)

    def _adopt(self, f: Frame) -> None:
        """Frame f (just filled) sets the extent, the sums and the output."""
        s = self._s
        s.lo, s.hi = float(f.th.min()), float(f.th.max())
        sw, s_th, s_th2, s_w2 = frame_moments(f.F)
        ok, th, var = md.theta_moments(sw, s_th, s_th2)
        if ok:
            self._theta, self._std = md.report(th, var, self.std_inflation)
            self._std_post = self._std
            s.sw, s.sw2 = sw, s_w2

    # ------------------------------------------------------------------- step
    def step(self, u_prev: float, y: float | None) -> None:
        """Predict with eq. (3) and u_prev, update with the wattmeter y (eq. 4) unless None;
        the reported std widened where the filter is known to get stuck (reported_std)."""
        u = float(u_prev)
        if y is None:
            yk = math.nan
        else:
            yk = float(y)
            if yk != yk:  # a NaN reading is rejected, not missing
                yk = math.inf
        code, th, sd = rc.filter_tick(self._S, self._b.FB, self._mats, self._ztab, u, yk)
        if code:
            th, sd = self._events(code, th, sd, u, yk)
        self._theta, self._std = th, sd

    def _events(self, code: int, th: float, sd: float, u: float, yk: float
                ) -> tuple[float, float]:
        """The rare outcomes of filter_tick: (theta, reported std)."""
        s = self._s
        if code & rc.NEED_OFFS:  # the next block of window offsets (pairs)
            s.offs[:] = self._rng.integers(0, NORMAL_TABLE, size=s.offs.size)
            s.koff = 0.0
            code, th, sd = rc.filter_tick(self._S, self._b.FB, self._mats, self._ztab, u, yk)
            if not code:
                return th, sd
        if code & rc.REJECTED:
            self.rejected += 1
        elif code & rc.CAREFUL_RUN:
            self.careful_updates += 1
        act = code & 3
        if not (act or code & rc.LEAVE_KF):
            return th, sd  # the reported std already
        self._theta, self._std_post = th, sd
        if code & rc.LEAVE_KF:
            self._from_kalman(int(s.o1))
        elif act == rc.LOST:
            self._lost(yk if md.Y_MIN_W < yk < md.Y_MAX_W else None)
        elif act == rc.RESAMPLE:
            self._resample(int(s.target))
        else:  # to the Kalman filter
            floor = (KF_STEADY_SD_PER_ALPHA * self.noise_scale) ** 2
            ks.moment_match(self._b.cur, float(s.sw), s.kf_x, floor)
            s.in_kf = 1.0
        return self._theta, md.reported_std(self._theta, self._std_post, u, s.lock_below,
                                         s.lock_var, s.lock_u)

    def _resample(self, n_new: int) -> None:
        """Systematic resampling into n_new particles (weights back to 1)."""
        b, s = self._b, self._s
        cur = int(s.cur)
        nb = self._banks[n_new]
        if nb is b:
            self.resamples += 1
        else:
            self.resizes += 1
        dst = b.frames[1 - cur] if nb is b else nb.frames[cur]
        if pf_resample(b.FB[cur], dst.F, n_new, float(self._rng.random())) != n_new:
            self._lost(None)  # broken weights (never seen: a tick with no weight is LOST)
            return
        if nb is b:
            s.cur = 1 - cur
        self._b = nb
        s.sw = s.sw2 = float(n_new)

    def _lost(self, y: float | None) -> None:
        """Divergence (no weight left, NaN): restart from the broad prior, count it."""
        self.resets += 1
        self._s.gated = self._s.in_kf = 0.0
        self._fill("broad", y)

    def _from_kalman(self, o1: int) -> None:
        """Back to particles: draw them from the Kalman Gaussian (restart if it is broken)."""
        s = self._s
        s.in_kf = 0.0
        if not ks.usable(s.kf_x):
            self._lost(None)
            return
        low = s.kf_x[0] - 3.0 * math.sqrt(s.kf_x[3]) < s.low_enter
        b = self._banks[self._n_low if low else self._n_high]
        n, z = b.n, self._normals
        o2, o3 = (o1 + 7919) % NORMAL_TABLE, (o1 + 15859) % NORMAL_TABLE
        ks.draw_from(s.kf_x, b.cur, z[o1:o1 + n], z[o2:o2 + n], z[o3:o3 + n])
        self._b = b
        self._adopt(b.cur)


def make_production_estimator(noise_scale: float = 1.0,
                              model: ThrottleModel = PAPER_THROTTLE) -> ThrottleParticleFilter:
    """The ECU's throttle estimator (registry name 'production'), see ThrottleParticleFilter; the
    particle counts per noise level: docs/models.md, "Production throttle estimator"."""
    n_low = N_LOW_NOISY if noise_scale > NOISY_ALPHA else DEFAULT_N_LOW
    return ThrottleParticleFilter(noise_scale, n_low=n_low, model=model)
