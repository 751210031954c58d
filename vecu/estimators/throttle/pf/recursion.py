"""One tick of the throttle particle filter, written once: `filter_tick` (vecu.kernels) checks u
and y, runs a Kalman-stretch tick (pf.kalman_stretch) or a particle tick (pf_tick: pf.update,
redo, renormalise, resample or hand-over) on the state record; rare outcomes go back to
pf.filter, flagged in the return code.
"""



from __future__ import annotations

import math

from vecu.estimators.throttle.pf.kalman_stretch import mode3_tick
from vecu.estimators.throttle.pf.model import Y_MAX_W, Y_MIN_W, report, reported_std, theta_moments
from vecu.estimators.throttle.pf.state import state_of
from vecu.estimators.throttle.pf.update import CAREFUL, PRIOR, UPDATE, pf_step
from vecu.kernels import kernel
from vecu.models.throttle import THETA_MAX_DEG

OUTLIER_FIT = 1e-12  # y is an outlier if the mean likelihood ratio is below this (> 7 sigma)
MAX_GATED_IN_ROW = 3  # at most this many outliers in a row are rejected, then y is believed
SURPRISE_FIT = 1e-3  # below this: clamp the proposal correction, likelihoods in the log domain

# filter_tick's code: the action in bits 0-1, then flags
GO_ON, RESAMPLE, TO_KALMAN, LOST = range(4)
REJECTED = 4  # y gated out (an outlier) or implausible
CAREFUL_RUN = 8  # the careful update ran
LEAVE_KF = 16  # the Kalman filter hands back to the particles
NEED_OFFS = 32  # no window offsets left: refill them and call again (nothing done yet)

ESS_FRACTION = 0.5  # resample when ESS < ESS_FRACTION * N


@kernel(error_model="numpy")
def pf_tick(FB, cur, mats, s, ztab, u, y, o1, o2, gated, check_kf):
    """One particle tick of bank FB from frame cur into the other: pf_step (with y unless NaN),
    redone with the same draws when the weight sum kept no more than SURPRISE_FIT of the last
    (as an outlier if the likelihood ratio is not above OUTLIER_FIT and fewer than
    MAX_GATED_IN_ROW were rejected in a row, else the careful update); renormalising; then
    resample (resample_target) or (check_kf) a hand-over when all theta are in kf_enter[0:2] and
    all i > kf_enter[2]. (code, target count, gated, theta, std); broken moments: LOST."""
    n = FB.shape[2]
    lo0, hi0, sw_old = s.lo, s.hi, s.sw
    rej = 0
    mode = UPDATE if y == y else PRIOR
    yc = y + s.y_shift
    while True:
        sw, s_th, s_th2, s_w2, lo, hi, ci_min = pf_step(FB, cur, mats, s, ztab, u, lo0, hi0,
                                                        o1, o2, mode, yc, check_kf)
        ok, th, var = theta_moments(sw, s_th, s_th2)
        if mode != UPDATE or (ok and sw > SURPRISE_FIT * sw_old):
            break
        if not (ok and sw / sw_old > OUTLIER_FIT) and gated < MAX_GATED_IN_ROW:
            gated += 1  # rare: redo as an outlier
            rej = REJECTED
            mode = PRIOR
        else:  # rare: redo with care
            rej = CAREFUL_RUN
            mode = CAREFUL
    if mode != PRIOR:
        gated = 0
    s.lo = lo
    s.hi = hi if lo <= s.bounds[2] else THETA_MAX_DEG
    if not ok:  # NaN or no weight left
        return LOST | rej, n, gated, 0.0, 0.0
    th, sd = report(th, var, s.inflation)
    if sw < 1e-150:  # weights only shrink (likelihoods <= 1): renormalise
        inv = 1.0 / sw
        dst = FB[1 - cur]
        for j in range(n):
            dst[6, j] = dst[6, j] * inv
        s_w2 = s_w2 * inv * inv
        sw = 1.0
    s.sw = sw
    s.sw2 = s_w2
    target = n
    if lo < s.low_enter:
        target = int(s.n_low)
    elif lo > s.low_exit:
        target = int(s.n_high)
    if target != n or sw * sw < ESS_FRACTION * n * s_w2:
        return RESAMPLE | rej, target, gated, th, sd
    kf = s.kf_enter
    if lo > kf[0] and check_kf and hi < kf[1] and ci_min > kf[2]:
        return TO_KALMAN | rej, n, gated, th, sd
    return GO_ON | rej, n, gated, th, sd


@kernel(error_model="numpy")
def filter_tick(S, FB, mats, ztab, u, y):
    """One tick on the state vector S (pf.state) with the particle bank FB (frames 0 and 1,
    the scratch rows in 2): predict with u (non-finite: 0), update with y (NaN: none; outside
    (Y_MIN_W, Y_MAX_W): rejected). Returns (code, theta, std): the reported std
    (reported_std) unless code has an action or LEAVE_KF (then the posterior's: the filter
    finishes the tick)."""
    s = state_of(S)
    offs = s.offs
    k = int(s.koff)
    if k + 1 >= len(offs):
        return NEED_OFFS, 0.0, 0.0
    o1 = int(offs[k])
    o2 = int(offs[k + 1])
    s.koff = k + 2
    s.o1 = o1
    steps = s.steps + 1.0
    s.steps = steps
    uf = u if math.isfinite(u) else 0.0
    code = 0
    if y == y and not (Y_MIN_W < y < Y_MAX_W):
        code = REJECTED
        y = math.nan
    gated = int(s.gated)
    if s.in_kf != 0.0:
        status, leave, th, sd = mode3_tick(s.kf_x, s.kf_coef, s.kf_prm, uf, y,
                                           gated < MAX_GATED_IN_ROW, s.kf_cfg)
        if status == 2:
            s.gated = gated + 1
            code |= REJECTED
        elif status == 1:
            s.gated = 0.0
        s.ksteps += 1.0
        if leave:
            return code | LEAVE_KF, th, sd
    else:
        cur = int(s.cur)
        check = s.use_kf != 0.0 and steps % s.kf_every == 0.0
        pc, target, gated, th, sd = pf_tick(FB, cur, mats, s, ztab, uf, y, o1, o2, gated,
                                            check)
        s.gated = gated
        code |= pc
        act = pc & 3
        if act != LOST:
            s.cur = 1 - cur
        if act == RESAMPLE:
            s.target = target
        if act != 0:  # the std as the posterior's: the filter finishes the tick
            return code, th, sd
    return code, th, reported_std(th, sd, u, s.lock_below, s.lock_var, s.lock_u)
