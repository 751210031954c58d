"""One tick of the production throttle estimator in one compiled call (numba backend).

ThrottleParticleFilter.step under numba is `filter_tick(S, FB, mats, ztab, u, y)`: the
window offsets of the normal table, the checks of u and y, a Kalman-stretch tick (mode3_tick)
or a particle tick (pf_tick: eq. 3 / eq. 4 step, redo, decisions) with its frame swap, the
counters of every tick and the reported std (reported_std). Six arguments, all the state in
one float vector S (layout below; ThrottleParticleFilter keeps views of its parts), so numba's
dispatch and the Python around it cost little. What is rare goes back to Python, flagged in
the returned code: refilling the offsets, resampling, a hand-over to or from the Kalman filter,
a restart. The python backend runs the same decisions in ThrottleParticleFilter's numpy path
(the reference), on the same S.
"""

# ruff: noqa: FURB136 (explicit selects: their NaN order, the same compiled and in Python)

from __future__ import annotations

import math

from vecu.estimators.throttle.pf_kernels import (
    LOST,
    MAX_GATED_IN_ROW,
    REJECTED,
    RESAMPLE,
    pf_tick,
)
from vecu.estimators.throttle.pf_parts import MAX_STD_DEG, Y_MAX_W, Y_MIN_W, mode3_tick_buf
from vecu.kernels import kernel

# S: pf_tick's st (0-5), then
S_GATED = 6  # outliers rejected in a row
S_STEPS = 7  # ticks so far
S_CUR = 8  # which of the bank's two frames holds the particles (0 / 1)
S_KOFF = 9  # next unused entry of the window offsets
S_INKF = 10  # 1 during a Kalman stretch
S_KSTEPS = 11  # Kalman-stretch ticks so far
S_TARGET = 12  # RESAMPLE: the particle count to resample into
S_O1 = 13  # the tick's first window offset (a hand-over from the Kalman filter draws there)
S_USEKF = 14  # 1: Kalman stretches allowed
S_KF_EVERY = 15  # ticks between checks of the Kalman hand-over condition
S_LOCK_BELOW = 16  # reported_std's theta bound
S_LOCK_VAR = 17  # reported_std's added variance
S_LOCK_U = 18  # reported_std's input bound
S_CST = 20  # pf_step's constants (step_constants, 13)
S_CFG = 36  # pf_tick's config (tick_config, 9)
S_KF = 48  # ModeThreeKalman.buf (32)
S_OFFS = 80  # the window offsets (pairs), to the end of S
N_CST, N_CFG, N_KF = 13, 9, 32

# filter_tick's code: pf_tick's action in bits 0-1 (GO_ON, RESAMPLE, TO_KALMAN, LOST), REJECTED
# (4: y gated out or implausible), CAREFUL_RUN (8), and
LEAVE_KF = 16  # the Kalman filter hands back to the particles
NEED_OFFS = 32  # no window offsets left: refill S's and call again (nothing done yet)


@kernel
def reported_std(th: float, sd: float, u: float, lock_below: float, lock_var: float,
                 lock_u: float) -> float:
    """The reported theta std: the posterior's sd, with lock_var added in quadrature while the
    filter is prone to be stuck below the mode-3 bound (theta <= lock_below and u > lock_u;
    False for NaN u), capped at MAX_STD_DEG (docs/models.md, Consistency)."""
    if th <= lock_below and u > lock_u:
        v = math.sqrt(sd * sd + lock_var)
        return MAX_STD_DEG if v > MAX_STD_DEG else v
    return sd


@kernel(error_model="numpy")
def filter_tick(S, FB, mats, ztab, u, y):
    """One tick on the state S (see the module) with the particle bank FB (frames 0 and 1, the
    scratch rows in 2): predict with u (non-finite: 0), update with y (NaN: none; outside
    (Y_MIN_W, Y_MAX_W): rejected). Returns (code, theta, std): the reported std
    (reported_std) unless code has an action or LEAVE_KF (then the posterior's: the filter
    finishes the tick in Python)."""
    k = int(S[S_KOFF])
    if S_OFFS + k + 1 >= S.shape[0]:
        return NEED_OFFS, 0.0, 0.0
    o1 = int(S[S_OFFS + k])
    o2 = int(S[S_OFFS + k + 1])
    S[S_KOFF] = k + 2
    S[S_O1] = o1
    steps = S[S_STEPS] + 1.0
    S[S_STEPS] = steps
    uf = u if math.isfinite(u) else 0.0
    code = 0
    if y == y and not (Y_MIN_W < y < Y_MAX_W):
        code = REJECTED
        y = math.nan
    gated = int(S[S_GATED])
    if S[S_INKF] != 0.0:
        status, leave, th, sd = mode3_tick_buf(S[S_KF:S_KF + N_KF], uf, y,
                                               gated < MAX_GATED_IN_ROW)
        if status == 2:
            S[S_GATED] = gated + 1
            code |= REJECTED
        elif status == 1:
            S[S_GATED] = 0.0
        S[S_KSTEPS] += 1.0
        if leave:
            return code | LEAVE_KF, th, sd
    else:
        cur = int(S[S_CUR])
        check = S[S_USEKF] != 0.0 and steps % S[S_KF_EVERY] == 0.0
        pc, target, gated, th, sd = pf_tick(
            FB[cur], FB[1 - cur], mats, S[S_CST:S_CST + N_CST], ztab, FB[2], uf, y, o1, o2,
            S[0:6], S[S_CFG:S_CFG + N_CFG], gated, check)
        S[S_GATED] = gated
        code |= pc
        act = pc & 3
        if act != LOST:
            S[S_CUR] = 1 - cur
        if act == RESAMPLE:
            S[S_TARGET] = target
        if act != 0:  # the std as the posterior's: the filter finishes the tick
            return code, th, sd
    return code, th, reported_std(th, sd, u, S[S_LOCK_BELOW], S[S_LOCK_VAR], S[S_LOCK_U])

