"""Compiled particle-mode step of the production throttle estimator (numba backend only).

Loop versions of ThrottleParticleFilter's numpy step (vecu.estimators.throttle.production):
`pf_step` = _predict + (_prior_current | _update | careful _update) + the moments of _summarise
in one call (branch-free loops that LLVM vectorises, the likelihoods' exp included: it is
vecu.kernels.exp.exp_poly, plain arithmetic, not a libm call per particle; only the careful
update's log and the sequential sums stay scalar), `pf_resample` = systematic_counts + the copy
of _resample, `pf_tick` = ThrottleParticleFilter._step's particle tick around pf_step (its
redo, renormalising and decisions; pf_advance: _propagate's bookkeeping). They work in place
on the Frame matrices F (rows theta, rho, i, 1, sgn rho, theta^2, weight) and read the same normal table at the same offsets, so they make the same
random draws. The prediction is the numpy code's arithmetic, operation by operation (no
fastmath, no FMA contraction); the update computes 1 / h^2 once (numpy: two divisions) and
exp_poly (<= 1 ulp, numpy's exp rounds otherwise), so the results agree with numpy's to
rounding (as do BLAS's eq. 3 matmul and the moments' gemv); the resampling counts (sequential
cumulative sum, as numpy's cumsum) are bit-identical for identical weights. The CAN golden log
is bit-identical under both backends (tests/test_golden_run.py).

The Python backend never calls these as plain Python (far too slow): it keeps the numpy path,
which is the reference. The kernels are plain Python functions all the same (tested that way on
small sets, with or without numba).
"""

# The explicit `a if a < b else b` selects keep numpy's NaN semantics (np.minimum / np.clip
# propagate NaN; Python's min / max depend on the argument order):
# ruff: noqa: FURB136

from __future__ import annotations

import math

import numpy as np

from vecu.estimators.throttle.pf_parts import report, theta_moments
from vecu.kernels import kernel
from vecu.kernels.exp import exp_poly
from vecu.models.throttle import THETA_MAX_DEG

# pf_step modes
PRIOR = 0  # no measurement: i from its prior, weights unchanged
UPDATE = 1  # linearised optimal proposal, predictive-likelihood weights
CAREFUL = 2  # the same with the clamped correction and log-domain weights

# the particle tick's decisions (ThrottleParticleFilter._step; pf_tick compiled)
ESS_FRACTION = 0.5  # resample when ESS < ESS_FRACTION * N
OUTLIER_FIT = 1e-12  # y is an outlier if the mean likelihood ratio is below this (> 7 sigma)
MAX_GATED_IN_ROW = 3  # at most this many outliers in a row are rejected, then y is believed
SURPRISE_FIT = 1e-3  # below this: clamp the proposal correction, likelihoods in the log domain

# pf_tick's actions (code & 3; code & 4: y rejected as an outlier, & 8: careful update)
GO_ON, RESAMPLE, TO_KALMAN, LOST = range(4)
REJECTED = 4
CAREFUL_RUN = 8
# layout of pf_tick's state vector st (read and written) and of its config vector (tick_config)
ST_LO, ST_HI, ST_SW, ST_SW2, ST_HI_EXT, ST_CI_MIN = range(6)
_C_YSHIFT, _C_INFL, _C_NLOW, _C_NHIGH, _C_LOW_ENTER, _C_LOW_EXIT, _C_KF0, _C_KF1, _C_KF2 = range(9)

# layout of the constants vector of pf_step (see step_constants)
_INV_C2, _KAPPA, _NEG_K2, _NEG_FOUR_S2, _CLIP_LO, _CLIP_HI, _B0 = range(7)


_BOUND0 = _B0 + 4  # the class bounds (1, b1, b2) follow the four classes' b


def step_constants(s_i: float, class_b: tuple[float, ...], r_watt: float = 1.0,
                   bounds: tuple[float, float, float] = (1.0, 8.0, 16.0)) -> np.ndarray:
    """Constants of pf_step, computed exactly as Bank / ThrottleParticleFilter._update do
    (r_watt: the wattmeter noise variance HH^T; bounds: the class bounds 1, b1, b2 in deg)."""
    inv_c = 1.0 / (2.0 * s_i)
    kappa = np.sqrt(0.5) * inv_c
    s2 = s_i * s_i
    return np.array([r_watt * (inv_c * inv_c), kappa, -kappa * kappa, -4.0 * s_i * s_i,
                     -0.25 / s2, 0.125 / s2, *class_b, *bounds], dtype=np.float64)


@kernel(error_model="numpy")
def eq3_row(out, th0, rh0, ci0, mats, cst, u, r, c0, c1, c2, c3, z, theta_row):
    """Row r (0 theta, 1 rho, 2 i) of eq. (3) for every particle into out, each with its own
    class: c_s for the slot s = the number of class bounds (1, b1, b2) below its theta (NaN:
    slot 0), picked by selects (no branch, vectorises); the same arithmetic as pf_step's
    per-class passes (the i row's constant b_c u); theta_row: + the noise z, clipped to
    [0, 90]. pf_step's pass when several classes are present."""
    n = th0.shape[0]
    k0, k1, k2 = cst[_BOUND0], cst[_BOUND0 + 1], cst[_BOUND0 + 2]
    ra, rb, rc, rd = 3 * c0 + r, 3 * c1 + r, 3 * c2 + r, 3 * c3 + r
    a0, a1, a2, a3, a4 = mats[ra, 0], mats[ra, 1], mats[ra, 2], mats[ra, 3], mats[ra, 4]
    b0, b1, b2, b3, b4 = mats[rb, 0], mats[rb, 1], mats[rb, 2], mats[rb, 3], mats[rb, 4]
    d0, d1, d2, d3, d4 = mats[rc, 0], mats[rc, 1], mats[rc, 2], mats[rc, 3], mats[rc, 4]
    e0, e1, e2, e3, e4 = mats[rd, 0], mats[rd, 1], mats[rd, 2], mats[rd, 3], mats[rd, 4]
    if r == 2:
        a3, b3, d3, e3 = (cst[_B0 + c0] * u, cst[_B0 + c1] * u, cst[_B0 + c2] * u,
                          cst[_B0 + c3] * u)
    for j in range(n):
        t0 = th0[j]
        x1 = rh0[j]
        g1, g2, g3 = t0 > k0, t0 > k1, t0 > k2
        sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
        m0 = e0 if g3 else (d0 if g2 else (b0 if g1 else a0))
        m1 = e1 if g3 else (d1 if g2 else (b1 if g1 else a1))
        m2 = e2 if g3 else (d2 if g2 else (b2 if g1 else a2))
        m3 = e3 if g3 else (d3 if g2 else (b3 if g1 else a3))
        m4 = e4 if g3 else (d4 if g2 else (b4 if g1 else a4))
        t = m0 * t0 + m1 * x1 + m2 * ci0[j] + m3 + m4 * sg
        if theta_row:
            t = t + z[j]
            t = 90.0 if t > 90.0 else t
            t = 0.0 if t < 0.0 else t
        out[j] = t


@kernel(error_model="numpy")  # x / 0 -> inf / NaN as numpy, no check per division
def pf_step(src, dst, mats, cst, ztab, tmp, u, lo_prev, hi_prev, o1, o2, mode, yc):
    """One particle-mode step from frame src into frame dst (rows 0-2 and 6 written).

    mats: the 12x5 class matrices (rows 3c..3c+2; the b*u entries are taken from cst instead),
    cst: step_constants, ztab: rows theta noise / prior current noise / proposal noise of the
    normal table, tmp: 3xn scratch, lo_prev / hi_prev: the filter's _lo / _hi (the classes
    from lo_prev's to hi_prev's are evaluated, one vectorised pass each; only the class of
    lo_prev if it is mode 3), yc = y + the filter's y shift. Separate branch-free passes so
    that LLVM vectorises all but the careful update's log and the sequential sums.
    Returns (sum w, sum w theta, sum w theta^2, sum w^2, min theta, max theta, min i); min / max
    are NaN if any value is NaN (as numpy's reductions).
    """
    n = src.shape[1]
    th0, rh0, ci0, w0 = src[0], src[1], src[2], src[6]
    th, rh, ci, w = dst[0], dst[1], dst[2], dst[6]
    zth, zi, zq = ztab[0, o1:o1 + n], ztab[1, o2:o2 + n], ztab[2, o2:o2 + n]
    t1, q, t3 = tmp[0], tmp[1], tmp[2]
    # bisect.bisect_left((1, b1, b2), x): the number of bounds below x (0 for NaN)
    k0, k1, k2 = cst[_BOUND0], cst[_BOUND0 + 1], cst[_BOUND0 + 2]
    c_lo = (1 if lo_prev > k0 else 0) + (1 if lo_prev > k1 else 0) + (1 if lo_prev > k2 else 0)
    c_hi = (1 if hi_prev > k0 else 0) + (1 if hi_prev > k1 else 0) + (1 if hi_prev > k2 else 0)
    # eq. (3): th = mats row 3c . [theta, rho, i, 1, sgn rho] (+ noise, clipped), likewise rho
    # and the predicted current m (into row ci; its constant column is b_c u). Every particle's
    # class lies between those of lo_prev and hi_prev: one pass per class present, class c
    # overwriting the particles above its lower bound (the numpy path's pick of the class by
    # theta; NaN theta: the lowest class), so every loop is branch-free and vectorises: one
    # class, one pass; several, one pass per row with the class picked per particle (eq3_row,
    # the same arithmetic; a pass per class costs more from two classes on).
    c_end = 3 if (c_lo == 3 or c_hi < c_lo) else c_hi  # c_hi < c_lo: hi_prev NaN
    if c_end > c_lo:  # several classes: one pass per row, the class picked per particle
        # (slot s = the bounds below theta -> class clamp(s, c_lo, c_end))
        s1 = c_lo if c_lo > 1 else (1 if c_end > 1 else c_end)
        s2 = c_lo if c_lo > 2 else (2 if c_end > 2 else c_end)
        eq3_row(th, th0, rh0, ci0, mats, cst, u, 0, c_lo, s1, s2, c_end, zth, True)
        eq3_row(rh, th0, rh0, ci0, mats, cst, u, 1, c_lo, s1, s2, c_end, zth, False)
        eq3_row(ci, th0, rh0, ci0, mats, cst, u, 2, c_lo, s1, s2, c_end, zth, False)
        c_end = -1  # done
    for c in range(c_lo, c_end + 1):
        r = 3 * c
        a0, a1, a2, a3, a4 = mats[r, 0], mats[r, 1], mats[r, 2], mats[r, 3], mats[r, 4]
        b0, b1, b2, b3, b4 = (mats[r + 1, 0], mats[r + 1, 1], mats[r + 1, 2], mats[r + 1, 3],
                              mats[r + 1, 4])
        d0, d1, d2, d3, d4 = (mats[r + 2, 0], mats[r + 2, 1], mats[r + 2, 2], cst[_B0 + c] * u,
                              mats[r + 2, 4])
        first = c == c_lo
        kb = cst[_BOUND0 + c - 1] if c > 0 else 0.0  # class >= c: theta > kb
        # one output row per loop: few enough arrays for LLVM's alias checks, so it vectorises
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)  # NaN rho: all rows NaN anyway
            t = a0 * th0[j] + a1 * x1 + a2 * ci0[j] + a3 + a4 * sg
            t = t + zth[j]
            t = 90.0 if t > 90.0 else t
            t = 0.0 if t < 0.0 else t  # numpy clips all at 0 if the minimum is below: same
            th[j] = t if (first or th0[j] > kb) else th[j]
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
            t = b0 * th0[j] + b1 * x1 + b2 * ci0[j] + b3 + b4 * sg
            rh[j] = t if (first or th0[j] > kb) else rh[j]
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
            t = d0 * th0[j] + d1 * x1 + d2 * ci0[j] + d3 + d4 * sg
            ci[j] = t if (first or th0[j] > kb) else ci[j]
    if mode == 0:  # prior current, weights unchanged
        for j in range(n):
            ci[j] = ci[j] + zi[j]
            w[j] = w0[j]
    elif mode == 1:  # the linearised optimal proposal, operation by operation as
        # ThrottleParticleFilter._update, fused into one loop (no scratch rows)
        inv_c2, kappa, neg_k2 = cst[_INV_C2], cst[_KAPPA], cst[_NEG_K2]
        neg_four_s2 = cst[_NEG_FOUR_S2]
        for j in range(n):
            m = ci[j]
            h2 = m * m
            h2 = h2 + inv_c2  # S / (2s)^2
            inv = 1.0 / h2  # one division (numpy: two; the same to rounding)
            qj = kappa * math.sqrt(inv)  # sqrt(0.5 / S)
            tj = neg_k2 * inv  # -0.5 / S
            rr = yc - h2  # r
            tj = rr * tj
            w[j] = w0[j] * (qj * exp_poly(rr * tj))  # likelihood up to a constant
            tj = tj * m
            tj = tj * neg_four_s2
            tj = tj + m
            ci[j] = tj + qj * zq[j]
    else:  # careful: the same with the correction clamped, likelihoods scaled to a maximum
        # of 1 in the log domain
        inv_c2, kappa, neg_k2 = cst[_INV_C2], cst[_KAPPA], cst[_NEG_K2]
        for j in range(n):
            m = ci[j]
            h2 = m * m
            h2 = h2 + inv_c2
            inv = 1.0 / h2
            q[j] = kappa * math.sqrt(inv)
            tj = neg_k2 * inv
            rr = yc - h2
            tj = rr * tj
            t3[j] = tj
            t1[j] = rr * tj
        clip_lo, clip_hi = cst[_CLIP_LO], cst[_CLIP_HI]
        for j in range(n):
            tj = t3[j]
            t3[j] = clip_lo if tj < clip_lo else (clip_hi if tj > clip_hi else tj)
        for j in range(n):
            t1[j] = t1[j] + math.log(q[j])
        mx = t1[0]
        for j in range(1, n):
            v = t1[j]
            if not math.isnan(mx) and (v > mx or math.isnan(v)):
                mx = v
        for j in range(n):
            t1[j] = t1[j] - mx
        for j in range(n):
            t1[j] = exp_poly(t1[j])
        for j in range(n):
            w[j] = w0[j] * t1[j]
        neg_four_s2 = cst[_NEG_FOUR_S2]
        for j in range(n):
            m = ci[j]
            tj = t3[j] * m
            tj = tj * neg_four_s2
            tj = tj + m
            ci[j] = tj + q[j] * zq[j]
    # moments (sequential sums) and extremes, branch-free (a NaN theta makes s_th NaN; theta
    # is never infinite after the clip; ci_chk is NaN if some i is NaN or infinite)
    lo = th[0]
    hi = lo
    ci_min = ci[0]
    ci_chk = 0.0
    sw = 0.0
    s_th = 0.0
    s_th2 = 0.0
    s_w2 = 0.0
    for j in range(n):
        x = th[j]
        wj = w[j]
        sw += wj
        s_th += x * wj
        s_th2 += (x * x) * wj
        s_w2 += wj * wj
        lo = x if x < lo else lo
        hi = x if x > hi else hi
        v = ci[j]
        ci_min = v if v < ci_min else ci_min
        ci_chk += v * 0.0
    if math.isnan(s_th) or math.isnan(ci_chk):  # rare: NaN-propagating extremes, as numpy's
        lo = th[0]
        hi = lo
        ci_min = ci[0]
        for j in range(n):
            x = th[j]
            if not math.isnan(lo) and (x < lo or math.isnan(x)):
                lo = x
            if not math.isnan(hi) and (x > hi or math.isnan(x)):
                hi = x
            v = ci[j]
            if not math.isnan(ci_min) and (v < ci_min or math.isnan(v)):
                ci_min = v
    return sw, s_th, s_th2, s_w2, lo, hi, ci_min


@kernel(error_model="numpy")
def pf_resample(src, dst, n_new, u0):
    """Systematic resampling of src's particles into dst's n_new (rows 0-2 copied, weights 1).

    Copies of particle i: floor(W_i n_new / W + u0) - floor(W_{i-1} n_new / W + u0), W_i the
    cumulative weights (the last one absorbs the rounding: the total is n_new). Destination k
    takes the particle i with the k-th copy, i.e. the number of cumulative floors <= k: counted
    per floor value, then a running sum, so no branch depends on the weights (a copy loop per
    particle mispredicts on every particle). Returns n_new, or 0 if the weights are broken
    (sum not finite and > 0).
    """
    n = src.shape[1]
    total = 0.0
    for i in range(n):
        total += src[6, i]
    if not (total > 0.0 and total < math.inf):
        return 0
    scale = n_new / total
    hits = np.zeros(n_new + 1, dtype=np.int64)
    acc = 0.0
    for i in range(n - 1):
        acc += src[6, i]
        x = acc * scale
        x = x + u0
        ic = math.floor(x)
        hits[ic if ic < n_new else n_new] += 1
    run = 0
    for k in range(n_new):
        run += hits[k]
        dst[0, k] = src[0, run]
        dst[1, k] = src[1, run]
        dst[2, k] = src[2, run]
    for j in range(n_new):
        dst[6, j] = 1.0
    return n_new


# redo_kind's answers
KEEP, AS_OUTLIER, WITH_CARE = range(3)


@kernel
def redo_kind(sw: float, sw_old: float, gated: int) -> int:
    """After an update with y: KEEP the step if its weight sum kept more than SURPRISE_FIT of
    the last one's; else redo it AS_OUTLIER (predict only: the mean likelihood ratio sw / sw_old
    not above OUTLIER_FIT, fewer than MAX_GATED_IN_ROW rejected in a row) or WITH_CARE (the
    careful update). Both backends' particle ticks decide by it."""
    if sw > SURPRISE_FIT * sw_old:
        return KEEP
    if not sw / sw_old > OUTLIER_FIT and gated < MAX_GATED_IN_ROW:
        return AS_OUTLIER
    return WITH_CARE


@kernel
def resample_target(lo: float, n: int, sw: float, sw2: float, n_low: int, n_high: int,
                    low_enter: float, low_exit: float) -> int:
    """The particle count to resample into after a tick, 0 to keep the set: n_low while the
    lowest theta lo is below low_enter, n_high once it is above low_exit (else n); a change of
    count or an ESS sw^2 / sw2 below ESS_FRACTION n resamples. Both backends decide by it."""
    target = n_low if lo < low_enter else (n_high if lo > low_exit else n)
    if target != n or sw * sw < ESS_FRACTION * n * sw2:
        return target
    return 0


@kernel(error_model="numpy")
def pf_advance(src, dst, mats, cst, ztab, tmp, u, o1, o2, mode, yc, st, inflation):
    """pf_step from the state st's (lo, hi), then the filter's bookkeeping: st's lo, hi (hi is
    90 once lo is in mode 3), the extremes max theta / min i, and from the moments (sum w > 0,
    mean and variance finite) the output (report) with st's sum w and sum w^2. Returns
    (sum w, theta, std); sum w NaN if the moments are broken (st's sums left as they were)."""
    sw, s_th, s_th2, s_w2, lo, hi, ci_min = pf_step(src, dst, mats, cst, ztab, tmp, u,
                                                    st[ST_LO], st[ST_HI], o1, o2, mode, yc)
    st[ST_LO] = lo
    st[ST_HI] = hi if lo <= cst[_BOUND0 + 2] else THETA_MAX_DEG
    st[ST_HI_EXT] = hi
    st[ST_CI_MIN] = ci_min
    ok, th, var = theta_moments(sw, s_th, s_th2)
    if not ok:
        return math.nan, 0.0, 0.0
    t, sd = report(th, var, inflation)
    st[ST_SW] = sw
    st[ST_SW2] = s_w2
    return sw, t, sd


@kernel(error_model="numpy")
def pf_tick(src, dst, mats, cst, ztab, tmp, u, y, o1, o2, st, cfg, gated, check_kf):
    """One particle tick of ThrottleParticleFilter._step in one call: pf_advance with y (NaN:
    none); a step whose weight sum fell below SURPRISE_FIT of the last one is redone from src
    with the same draws, as an outlier (predict only; at most MAX_GATED_IN_ROW in a row) if
    below OUTLIER_FIT, else with the careful update; renormalisation below 1e-150; then the
    decision: resample (ESS < ESS_FRACTION N, or the particle count for st's lo: cfg's n_low
    below low_enter, n_high above low_exit), or (check_kf) hand over to the Kalman filter if
    all theta are in (kf0, kf1) and all i > kf2. cfg: tick_config. Returns (code, target
    count, gated, theta, std); code & 3 the action (GO_ON, RESAMPLE, TO_KALMAN, LOST: no
    weight left), code & REJECTED: y was gated out, code & CAREFUL_RUN: the careful update ran."""
    n = src.shape[1]
    infl = cfg[_C_INFL]
    lo0, hi0, sw_old = st[ST_LO], st[ST_HI], st[ST_SW]
    rej = 0
    if y == y:
        sw, th, sd = pf_advance(src, dst, mats, cst, ztab, tmp, u, o1, o2, UPDATE,
                                y + cfg[_C_YSHIFT], st, infl)
        kind = redo_kind(sw, sw_old, gated)
        if kind == KEEP:
            gated = 0
        else:  # rare: redo from src
            st[ST_LO] = lo0
            st[ST_HI] = hi0
            if kind == AS_OUTLIER:
                gated += 1
                rej = REJECTED
                sw, th, sd = pf_advance(src, dst, mats, cst, ztab, tmp, u, o1, o2, PRIOR, 0.0,
                                        st, infl)
            else:
                gated = 0
                rej = CAREFUL_RUN
                sw, th, sd = pf_advance(src, dst, mats, cst, ztab, tmp, u, o1, o2, CAREFUL,
                                        y + cfg[_C_YSHIFT], st, infl)
    else:
        sw, th, sd = pf_advance(src, dst, mats, cst, ztab, tmp, u, o1, o2, PRIOR, 0.0, st, infl)
    if not sw > 0.0:  # NaN or no weight left
        return LOST | rej, n, gated, th, sd
    if sw < 1e-150:  # weights only shrink (likelihoods <= 1): renormalise
        inv = 1.0 / sw
        for j in range(n):
            dst[6, j] = dst[6, j] * inv
        st[ST_SW2] = st[ST_SW2] * inv * inv
        sw = 1.0
        st[ST_SW] = sw
    lo = st[ST_LO]
    target = resample_target(lo, n, sw, st[ST_SW2], int(cfg[_C_NLOW]), int(cfg[_C_NHIGH]),
                             cfg[_C_LOW_ENTER], cfg[_C_LOW_EXIT])
    if target:
        return RESAMPLE | rej, target, gated, th, sd
    if (lo > cfg[_C_KF0] and check_kf and st[ST_HI_EXT] < cfg[_C_KF1]
            and st[ST_CI_MIN] > cfg[_C_KF2]):
        return TO_KALMAN | rej, n, gated, th, sd
    return GO_ON | rej, n, gated, th, sd


def tick_config(y_shift: float, inflation: float, n_low: int, n_high: int, low_enter: float,
                low_exit: float, kf_enter: tuple[float, float, float]) -> np.ndarray:
    """pf_tick's config vector."""
    return np.array([y_shift, inflation, n_low, n_high, low_enter, low_exit, *kf_enter],
                    dtype=np.float64)
