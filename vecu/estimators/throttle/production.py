"""Production throttle-angle estimator: particle filter + Kalman stretches, few numpy calls.

Model (Vargas et al. 2015): the piecewise-affine eq. (3) with Table I, state x = [theta, rho, i],
theta in degrees and clipped to the stops [0, 90] after every step, process noise alpha*F with
F = diag(sqrt 0.35, 0, sqrt 0.18) per 1 ms step; wattmeter eq. (4) y = i^2 + v, v ~ N(0, 1)
(vecu.models.throttle; docs/models.md, "Production throttle estimator").

Why particles: y carries |i| only, theta is inferred through the dynamics, and near the mode
switches at 8 / 16 deg (rho flips its sign convention between mode 1 and modes 2/3; a mode-2 ->
mode-3 crossing with large rho throws theta up by tens of degrees and i up to 40 A) the posterior
is multi-modal; Gaussian filters lock there. The particle filter
  * draws i from the locally linearised optimal proposal p(i_k | x_{k-1}, y_k) (eq. 4
    linearised at each particle's predicted current m) and weights by the matching predictive
    likelihood N(y; m^2 + s^2, S), S = 1 + 4 m^2 s^2;
  * resamples (systematic) only when the effective sample size drops below N/2;
  * uses `n_low` particles while some particle is below LOW_ENTER_DEG (mode switches within
    reach) and `n_high` once all are above LOW_EXIT_DEG (the count changes by resampling);
  * hands over to a moment-matched Kalman filter (ModeThreeKalman) while the whole posterior is
    inside mode 3 with a surely positive current: there eq. (3) is linear (the 90 deg stop is
    handled by censored-Gaussian moments) and the Kalman filter is as accurate as the particles
    at a fraction of the cost.
rho is noise-free given (theta, rho, i), so each particle carries its exact rho.

Backends (vecu.kernels, VECU_KERNELS): under "python" the particle step is the numpy code of
pf_numpy (the reference) and a Kalman-stretch tick mode3_tick as plain Python; under "numba"
a whole tick, particle or Kalman, is one compiled call, filter_tick of
vecu.estimators.throttle.tick (pf_kernels.pf_tick around pf_step: same draws, same decisions,
results equal to rounding), all its state in one vector _S. The rare paths (offset refills,
fill, resampling, hand-overs) are the same Python under both.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.throttle.pf_kernels import (
    CAREFUL_RUN,
    KEEP,
    LOST,
    MAX_GATED_IN_ROW,
    REJECTED,
    RESAMPLE,
    ST_SW,
    ST_SW2,
    pf_resample,
    redo_kind,
    resample_target,
    step_constants,
    tick_config,
)
from vecu.estimators.throttle.pf_numpy import NumpyParticleStep
from vecu.estimators.throttle.pf_parts import (
    CLASS_BOUNDS_DEG,
    U_COL,
    Y_MAX_W,
    Y_MIN_W,
    Bank,
    ModeThreeKalman,
    class_b,
    class_bounds,
    class_matrix_stack,
    report,
    systematic_counts,
    theta_moments,
)
from vecu.estimators.throttle.tick import (
    LEAVE_KF,
    N_CFG,
    N_CST,
    N_KF,
    NEED_OFFS,
    S_CFG,
    S_CST,
    S_CUR,
    S_GATED,
    S_INKF,
    S_KF,
    S_KF_EVERY,
    S_KOFF,
    S_KSTEPS,
    S_LOCK_BELOW,
    S_LOCK_U,
    S_LOCK_VAR,
    S_O1,
    S_OFFS,
    S_STEPS,
    S_TARGET,
    S_USEKF,
    filter_tick,
    reported_std,
)
from vecu.kernels import backend
from vecu.models.throttle import (
    PAPER_THROTTLE,
    THETA_MAX_DEG,
    THETA_MIN_DEG,
    ThrottleModel,
)

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
OFFSET_BLOCK = 4096  # window offsets drawn per refill
# ESS_FRACTION, OUTLIER_FIT, MAX_GATED_IN_ROW, SURPRISE_FIT: pf_kernels (redo_kind and
# resample_target: the tick's decisions, written once for both backends)
KF_ENTER = (30.0, 85.0, 1.0)  # all particles: theta in (30, 85) deg, i > 1 A -> Kalman filter
# Kalman theta - 3 sigma < 22 deg, theta + 2 sigma > 90 deg (too much mass at the stop) or
# i - 3 sigma < 0.5 A -> particles again
KF_EXIT = (22.0, 2.0, 0.5)
KF_CHECK_EVERY = 8  # steps between checks of the KF_ENTER condition
KF_STEADY_SD_PER_ALPHA = 5.9  # measured steady-state Kalman theta std in mode 3, per unit alpha
KF_GATE = 49.0  # Kalman innovation outlier gate (r^2 / S, 7 sigma)
DEFAULT_STD_INFLATION = 1.2  # theta_std_deg = 1.2 x posterior std (calibration, docs/models.md)
# Stuck below the mode-3 bound (issue 30 item 5, docs/models.md "Consistency"): while the
# estimate is at or below b2 + LOCK_MARGIN_DEG and the command u exceeds LOCK_U_V, the filter
# sometimes misses a mode-2 -> mode-3 throw of the truth and its particles stay parked below b2
# with a posterior std of ~1 deg while the throttle is at 60-90 deg (the 1 h soak, seed 2026:
# errors of 50-80 deg for 300-500 ms, twice). There (1.4 % of the time) the reported variance
# gets LOCK_STD_DEG^2 added: the error there is 13.3 deg rms against a reported 6.6 deg (NEES
# 44-500 by angle), 12 deg brings it to about 1. The estimate itself is unchanged.
LOCK_U_V = 3.0
LOCK_MARGIN_DEG = 1.5
LOCK_STD_DEG = 12.0
# ufunc reductions and ndarray methods called directly: the np.* / .min() forms add a Python-level
# wrapper (~1 us a call, several calls a step); the results are the same
_min = np.minimum.reduce
_max = np.maximum.reduce


class ThrottleParticleFilter(NumpyParticleStep):
    """ThrottleEstimator: particle filter on eq. (3) / eq. (4), see the module docstring.

    step(u_prev, y): propagate with eq. (3) and u_prev (theta noise, clip), then update with y_k
    (eq. 4); y=None, non-finite or outside (Y_MIN_W, Y_MAX_W), or an isolated outlier: predict
    only. theta_deg / theta_std_deg: posterior mean / std of theta (std x `std_inflation`,
    floored at 0.3 deg, capped at 51 deg). Counters: resets (divergence restarts), rejected
    (y gated out), resamples, resizes (particle-count changes), kalman_steps, careful_updates
    (steps redone with the careful update).
    Deterministic: all randomness comes from PCG64(seed); reset() replays the same sequence.
    """

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
        r_watt = model.h_wattmeter * model.h_wattmeter
        self._s_th = max(a * f_diag[0], 1e-3)
        s = max(a * f_diag[2], 1e-3)  # prior std of the current's step noise
        self._s_i = s
        self._y_shift = r_watt / (4.0 * s * s) - s * s  # r = y - s^2 - m^2 = y + shift - h^2
        self._cb = cb = class_bounds(model)
        shift = cb[2] - CLASS_BOUNDS_DEG[2]  # the angle thresholds follow the mode-3 bound
        self._low_enter, self._low_exit = LOW_ENTER_DEG + shift, LOW_EXIT_DEG + shift
        self._kf_enter = (KF_ENTER[0] + shift, *KF_ENTER[1:])
        self._kf_exit = (KF_EXIT[0] + shift, *KF_EXIT[1:])
        self._lock_below = cb[2] + LOCK_MARGIN_DEG
        self._lock_var = float(lock_std_deg) ** 2  # 0: the posterior's std alone
        cls_b = class_b(model)
        self._n_high, self._n_low = int(n_high), int(n_low)
        # the whole state in one vector (vecu.estimators.throttle.tick), views of its parts
        self._S = S = np.zeros(S_OFFS + 2 * OFFSET_BLOCK)
        sel = S[S_CUR:S_CUR + 1]
        self._banks = {n: Bank(n, s, r_watt, cb, sel) for n in {self._n_high, self._n_low}}
        self._mats = class_matrix_stack(model)
        self._mviews = [self._mats[3 * c:3 * c + 3] for c in range(4)]
        self._bcol = self._mats[2::3, U_COL]
        self._bvec = np.array(cls_b)
        self._cls_b = cls_b
        self._yc = np.zeros(())  # 0-d array: y + shift of the current step
        self._kf = ModeThreeKalman(self._s_th ** 2, s * s, model, KF_GATE,
                                   S[S_KF:S_KF + N_KF])
        self._kf.set_tick(*self._kf_exit, self.std_inflation)
        self._kconst = S[S_CST:S_CST + N_CST]  # the compiled step's constants
        self._kconst[:] = step_constants(s, cls_b, r_watt, cb)
        self._tcfg = S[S_CFG:S_CFG + N_CFG]
        self._tcfg[:] = tick_config(self._y_shift, self.std_inflation, self._n_low,
                                    self._n_high, self._low_enter, self._low_exit,
                                    self._kf_enter)
        self._st = S[:6]  # pf_tick's state (lo, hi, sw, sw2, extremes), kept in step
        self._offs = S[S_OFFS:]
        self._Sv: Any = S.data  # the same memory: Python's element access at half numpy's cost
        S[S_USEKF], S[S_KF_EVERY] = float(self.use_kalman), KF_CHECK_EVERY
        S[S_LOCK_BELOW], S[S_LOCK_VAR], S[S_LOCK_U] = self._lock_below, self._lock_var, LOCK_U_V
        self.resets = self.rejected = self.resamples = self.resizes = self.careful_updates = 0
        self.reset()

    # counters and flags kept in S (the compiled tick's state)
    steps = property(lambda self: int(self._Sv[S_STEPS]))
    kalman_steps = property(lambda self: int(self._Sv[S_KSTEPS]))
    _in_kf = property(lambda self: self._Sv[S_INKF] != 0.0,
                      lambda self, v: self._Sv.__setitem__(S_INKF, float(v)))
    _gated = property(lambda self: int(self._Sv[S_GATED]),
                      lambda self, v: self._Sv.__setitem__(S_GATED, float(v)))

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial prior ('rest': theta=|N(0,1)|, rho, i ~ N(0,1)) and the seed."""
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        self._normals = z = self._rng.standard_normal(NORMAL_TABLE + max(self._banks))
        self._ztab = np.empty((3, z.size))  # rows read by the compiled step
        self._zth, self._zi, self._zq = self._ztab
        np.multiply(z, self._s_th, out=self._zth)  # theta process noise
        np.multiply(z, self._s_i, out=self._zi)  # current process noise (prior draw)
        np.multiply(z, self._s_i * math.sqrt(2.0), out=self._zq)  # proposal noise, x sqrt(.5/S)
        self._S[S_KOFF] = self._offs.size  # none left: the first tick draws them
        self._gated = 0
        self._in_kf = False
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

    def _adopt(self, f) -> None:
        """Frame f (just filled) sets the extent, the sums and the output (also pf_tick's)."""
        self._lo, self._hi = float(f.th.min()), float(f.th.max())
        self._summarise(f)
        self._st[:4] = (self._lo, self._hi, self._sw, self._sw2)

    def _summarise(self, f) -> float:
        """Weighted moments of theta from one frame; returns the weight sum (bad: NaN)."""
        np.multiply(f.th, f.th, out=f.th2)
        mom = f.F.dot(f.w)  # sums of w * [theta, rho, i, 1, sgn rho, theta^2, w]
        return self._take_moments(float(mom[3]), float(mom[0]), float(mom[5]), float(mom[6]))

    def _take_moments(self, sw: float, s_th: float, s_th2: float, s_w2: float) -> float:
        """Output from the sums of w, w theta, w theta^2, w^2; returns sw (bad: NaN)."""
        ok, th, var = theta_moments.py(sw, s_th, s_th2)
        if not ok:
            return math.nan
        self._set_output(th, var)
        self._sw = sw
        self._sw2 = s_w2
        return sw

    def _set_output(self, th: float, var: float) -> None:
        self._theta, self._std = report.py(th, var, self.std_inflation)
        self._std_post = self._std

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
        return 0 if self._in_kf else self._b.n

    # ------------------------------------------------------------------- step
    def step(self, u_prev: float, y: float | None) -> None:
        """Predict with eq. (3) and u_prev, update with the wattmeter y (eq. 4) unless None;
        the reported std widened where the filter is known to get stuck (reported_std). Under
        numba one compiled call (tick.filter_tick), Python only for its rare events."""
        u = float(u_prev)
        if y is None:
            yk = math.nan
        else:
            yk = float(y)
            if yk != yk:  # a NaN reading is rejected, not missing
                yk = math.inf
        if backend() == "numba":
            code, th, sd = filter_tick.compiled(self._S, self._b.FB, self._mats, self._ztab, u,
                                                yk)
            if code:
                th, sd = self._events(code, th, sd, u, yk)
            self._theta, self._std = th, sd
            return
        self._step(u, yk)
        self._std = reported_std.py(self._theta, self._std_post, u, self._lock_below,
                                    self._lock_var, LOCK_U_V)

    def _events(self, code: int, th: float, sd: float, u: float, yk: float
                ) -> tuple[float, float]:
        """The rare outcomes of filter_tick, finished in Python: (theta, reported std)."""
        if code & NEED_OFFS:
            self._refill()
            code, th, sd = filter_tick.compiled(self._S, self._b.FB, self._mats, self._ztab,
                                                u, yk)
            if not code:
                return th, sd
        if code & REJECTED:
            self.rejected += 1
        elif code & CAREFUL_RUN:
            self.careful_updates += 1
        act = code & 3
        if not (act or code & LEAVE_KF):
            return th, sd  # the reported std already
        self._theta, self._std_post = th, sd
        if code & LEAVE_KF:
            self._from_kalman(int(self._S[S_O1]))
        elif act == LOST:
            self._lost(yk if Y_MIN_W < yk < Y_MAX_W else None)
        elif act == RESAMPLE:
            self._resample(int(self._S[S_TARGET]))
        else:
            self._to_kalman(self._b.cur, float(self._st[ST_SW]))
        return self._theta, reported_std.py(self._theta, self._std_post, u, self._lock_below,
                                            self._lock_var, LOCK_U_V)

    def _refill(self) -> None:
        """The next block of window offsets (pairs: theta noise, current noise)."""
        self._offs[:] = self._rng.integers(0, NORMAL_TABLE, size=self._offs.size)
        self._S[S_KOFF] = 0.0

    def _step(self, u: float, yk: float) -> None:
        """The python backend's tick (the reference; filter_tick's under numba)."""
        S = self._Sv
        k = int(S[S_KOFF])
        if S_OFFS + k + 1 >= len(S):
            self._refill()
            k = 0
        o1, o2 = int(S[S_OFFS + k]), int(S[S_OFFS + k + 1])
        S[S_KOFF] = k + 2.0
        S[S_STEPS] += 1.0
        if not math.isfinite(u):
            u = 0.0
        y: float | None = None
        if yk == yk:
            if Y_MIN_W < yk < Y_MAX_W:
                y = yk
            else:
                self.rejected += 1
        if self._in_kf:  # a Kalman-stretch tick: one kernel call (mode3_tick)
            yk, may_gate = math.nan if y is None else y, self._gated < MAX_GATED_IN_ROW
            status, leave, th, sd = self._kf.tick(u, yk, may_gate)
            if status == 2:
                self._gated += 1
                self.rejected += 1
            elif status == 1:
                self._gated = 0
            S[S_KSTEPS] += 1.0
            if leave:
                self._from_kalman(o1)
            else:
                self._theta = th
                self._std_post = sd  # step() reports from it
            return
        b = self._b
        f, g = b.cur, b.nxt
        sw_old = self._sw
        extent = self._lo, self._hi  # of frame f: a redo picks its mode classes from these
        sw = self._propagate(b, f, g, u, y, o1, o2, False)
        if y is not None:
            kind = redo_kind.py(sw, sw_old, self._gated)
            if kind == KEEP:
                self._gated = 0
            else:  # rare: redo this step as an outlier (predict only) or with care
                self._lo, self._hi = extent
                sw = self._replay(b, f, g, u, y, o1, o2, kind)
        if not sw > 0.0:  # NaN or no weight left
            self._lost(y)
            return
        b.swap()
        if sw < 1e-150:  # weights only shrink (likelihoods <= 1): renormalise
            inv = 1.0 / sw
            g.w *= inv
            self._sw2 = self._sw2 * inv * inv
            self._sw = sw = 1.0
        lo = self._lo
        target = resample_target.py(lo, b.n, sw, self._sw2, self._n_low, self._n_high,
                                    self._low_enter, self._low_exit)
        if target:
            self._resample(target)
        elif (lo > self._kf_enter[0] and self.use_kalman and self.steps % KF_CHECK_EVERY == 0
              and self._fits_kalman(g)):
            self._to_kalman(g, self._sw)

    def _fits_kalman(self, g) -> bool:
        """The rest of KF_ENTER: all theta below 85 deg and all currents above 1 A."""
        th_max, ci_min = float(_max(g.th)), float(_min(g.ci))
        return th_max < self._kf_enter[1] and ci_min > self._kf_enter[2]

    def _resample(self, n_new: int) -> None:
        """Systematic resampling into n_new particles (weights back to 1)."""
        b = self._b
        f = b.cur
        nb = self._banks[n_new]
        if nb is b:
            self.resamples += 1
        else:
            self.resizes += 1
        dst = b.nxt if nb is b else nb.cur
        u0 = float(self._rng.random())
        if backend() != "numba" or pf_resample.compiled(f.F, dst.F, n_new, u0) != n_new:
            counts = systematic_counts(b, f.w, n_new, u0)  # (broken weights raise here)
            f.top3.take(b.ar.repeat(counts), axis=1, out=dst.top3)
            dst.w.fill(1.0)
        if nb is b:
            b.swap()
        self._b = nb
        self._sw = self._sw2 = float(n_new)
        self._st[ST_SW] = self._st[ST_SW2] = self._sw

    def _lost(self, y: float | None) -> None:
        """Divergence (no weight left, NaN): restart from the broad prior, count it."""
        self.resets += 1
        self._gated = 0
        self._in_kf = False
        self._fill("broad", y)

    # -------------------------------------------------------- Kalman stretches
    def _to_kalman(self, f, sw: float) -> None:
        """All particles well inside mode 3 with a positive current (weight sum sw):
        moment-match them."""
        w = f.w * (1.0 / sw)
        mean = f.top3.dot(w)
        d = f.top3 - mean[:, None]
        cov = (d * w).dot(d.T)
        # A freshly collapsed cloud (e.g. right after a mode-2 -> 3 throw) can be narrower than
        # the truth's spread: hand over at least the steady-state mode-3 theta variance.
        floor = (KF_STEADY_SD_PER_ALPHA * self.noise_scale) ** 2
        if cov[0, 0] < floor:
            cov *= floor / max(float(cov[0, 0]), 1e-12)
        self._kf.load(mean, cov)
        self._in_kf = True

    def _from_kalman(self, o1: int) -> None:
        """Back to particles: draw them from the Kalman Gaussian (restart if it is broken)."""
        kf = self._kf
        self._in_kf = False
        if not (math.isfinite(kf.th + kf.rh + kf.ci + kf.p00 + kf.p11 + kf.p22)
                and kf.p00 > 0.0 and kf.p11 >= 0.0 and kf.p22 > 0.0):
            self._lost(None)
            return
        l00, l10, l11, l20, l21, l22 = kf.cholesky()
        low = kf.th - 3.0 * math.sqrt(kf.p00) < self._low_enter
        b = self._banks[self._n_low if low else self._n_high]
        f, n, z = b.cur, b.n, self._normals
        o2, o3 = (o1 + 7919) % NORMAL_TABLE, (o1 + 15859) % NORMAL_TABLE
        z0, z1, z2 = z[o1:o1 + n], z[o2:o2 + n], z[o3:o3 + n]
        np.clip(kf.th + l00 * z0, THETA_MIN_DEG, THETA_MAX_DEG, out=f.th)
        f.rh[:] = kf.rh + l10 * z0 + l11 * z1
        f.ci[:] = kf.ci + l20 * z0 + l21 * z1 + l22 * z2
        f.w.fill(1.0)
        self._b = b
        self._adopt(f)


def make_production_estimator(noise_scale: float = 1.0,
                              model: ThrottleModel = PAPER_THROTTLE) -> ThrottleParticleFilter:
    """The ECU's throttle estimator (registry name 'production'), see ThrottleParticleFilter.

    Near the mode switches the posterior is wider at the paper's noise (alpha = 1) than at a
    quiet throttle: at alpha = 1, 800 particles there (paired against 1000 over 16 held-out
    seeds x 200 k steps: error std +0.3 % +- 0.9 %; 600: +1.9 % +- 1.3 %, 500: +4.3 %), while
    at alpha = 0.3 600 suffice (docs/models.md).
    """
    n_low = N_LOW_NOISY if noise_scale > NOISY_ALPHA else DEFAULT_N_LOW
    return ThrottleParticleFilter(noise_scale, n_low=n_low, model=model)
