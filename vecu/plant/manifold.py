"""Intake manifold simulator: the stochastic truth of Dutka et al. 2006 (eq. 10, Section IV noise).
Kernels `plant_step` (eq. 1, eq. 5-6, eq. 9, Section IV's Q, clamps) and `measure` (Section IV's
R, sensor gains), driven by one loop, `truth_events`; noise rows come in blocks from one stream
(the block size never changes the numbers).
"""

# ruff: noqa: FURB136 (x if c else y in the kernels mirrors Python's min()/max(), NaN included)
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vecu.kernels import kernel
from vecu.models.manifold import (
    air_charge_of,
    event_coefficients,
    event_map,
    nominal_input,
    port_flow_of,
    sample_time,
    steady_state_vector,
    throttle_flow_of,
)
from vecu.models.manifold_integrator import _integrate_event as integrate_event
from vecu.models.manifold_integrator import tables
from vecu.models.manifold_params import (
    PAPER_NOISE,
    V8_5L7,
    ManifoldNoise,
    ManifoldParams,
)
from vecu.plant.drive_profile import DriveProfile, profile_at
from vecu.rng import rng_streams

# ------------------------------------------------------------------------- stochastic plant
# The truth's physical envelope: pressure and temperatures saturate here, so that any noise scale
# the parameter tree admits (<= 1e3) keeps the simulation finite (the event integrator fails at
# the model's own floor P_FLOOR_KPA). Nominal drives stay far inside (P_im 16..115 kPa, T 250..380
# K at noise_scale <= 10), where these bounds change nothing.
P_MIN_KPA, P_MAX_KPA = 5.0, 1000.0
T_MIN_K, T_MAX_K = 150.0, 1000.0


@dataclass(frozen=True)
class ManifoldPlantConfig:
    """noise_scale multiplies the standard deviations of the paper's Q and R (0: noise-free)."""

    engine: ManifoldParams = V8_5L7  # the simulated engine (the truth)
    noise_scale: float = 1.0
    noise: ManifoldNoise = PAPER_NOISE
    # measurement gain errors of the sensors (TA, P_im, T_im.out): y = G (x + v); 1 = exact
    # (Dutka Table 2 varies them by +-3 %, +-2 %, +-2 %)
    sensor_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # noise rows drawn at a time (the stream does not depend on it): not a parameter of the car
    block: int = field(default=1024, metadata={"param": False})


# plant constants vector (truth_events' pc)
(C_ZETA, C_OMEGA0, C_TAU, C_VCYL, C_NCYL, C_PA, C_TA, C_TCOOL, C_SQ0, C_SQ1, C_SQ2, C_SQ3,
 C_SR0, C_SR1, C_SR2, C_G0, C_G1, C_G2, C_PMIN, C_PMAX, C_TMIN, C_TMAX, C_DURATION,
 C_DT) = range(24)
N_PLANT_CONSTS = 24


@kernel
def measure(st, w, pc):
    """y_n = G (x_n + v_n): (TA rad, P_im kPa, T_im.out K) with the paper's R (Section IV; the
    noise row's entries 4-6) and the sensor gains G."""
    return ((st[1] + pc[C_SR0] * w[4]) * pc[C_G0], (st[3] + pc[C_SR1] * w[5]) * pc[C_G1],
            (st[5] + pc[C_SR2] * w[6]) * pc[C_G2])


@kernel
def plant_step(st, sp, n, p_a, t_a, t_cool, ts, w, pc, cst, cd_alpha, cd_table, prs, eta_rpm,
               eta_val):
    """One event of the truth in place on st = (u_prev, alpha, alpha_prev, P_im, T_im, T_meas):
    eq. 1, the event integrator of eq. 5-6, eq. 9, Section IV's Q from noise row w (entries 0-3)
    and the physical clamps; returns the sub-steps used."""
    u_prev, alpha, alpha_prev, p, t, tm = st[0], st[1], st[2], st[3], st[4], st[5]
    co = event_coefficients(ts, pc[C_ZETA], pc[C_OMEGA0], pc[C_TAU])
    p_n, t_n, m = integrate_event(p, t, alpha, p_a, t_a, t_cool, n, ts, cst, cd_alpha, cd_table,
                                  prs, eta_rpm, eta_val)
    alpha_n, tm_n = event_map(co, u_prev, alpha, alpha_prev, sp, t, tm)
    new_alpha = alpha_n + pc[C_SQ0] * w[0]
    v = p_n + pc[C_SQ1] * w[1]
    v = pc[C_PMIN] if pc[C_PMIN] > v else v
    new_p = pc[C_PMAX] if pc[C_PMAX] < v else v
    v = t_n + pc[C_SQ2] * w[2]
    v = pc[C_TMIN] if pc[C_TMIN] > v else v
    new_t = pc[C_TMAX] if pc[C_TMAX] < v else v
    v = tm_n + pc[C_SQ3] * w[3]
    v = pc[C_TMIN] if pc[C_TMIN] > v else v
    new_tm = pc[C_TMAX] if pc[C_TMAX] < v else v
    st[0], st[1], st[2], st[3], st[4], st[5] = sp, new_alpha, alpha, new_p, new_t, new_tm
    return m


# truth_events' row columns: the event's period, N, TA_SP, the readings (TA, P_im, T_im.out),
# the state before the event (6), the throttle and port flows, the CAC and the sub-steps used,
# its time on the float clock
(R_TS, R_N, R_SP, R_Y, R_X, R_MDOT_AT, R_MDOT_AC, R_CAC, R_M, R_T) = (0, 1, 2, 3, 6, 12, 13, 14,
                                                                    15, 16)
N_ROW = 17


@kernel
def truth_events(st, t_ns, t0_ns, time, ns_clock, prof_n, prof_sp, noise, pos, pc, c, cd_alpha,
                 cd_table, prs, eta_rpm, eta_val, times, rows):
    """The truth's events from the event at t_ns (ns, int; the profile started at t0_ns) and at
    `time` (s, float): per event k its time times[k] (ns) and rows[k] (R_* columns), st (the
    state) advanced in place, one noise row per event from pos on. Two clocks: t_{k+1} = t_k +
    max(1, round(T_s 1e9)) ns (ManifoldPart's), time_{k+1} = time_k + T_s (simulate's); the one
    named by ns_clock places the events on the profile. Stops before an event past the
    profile's end, when the noise rows run out or rows is full; returns (events, the next
    event's t_ns, its time, the next noise row)."""
    k = 0
    while k < len(rows) and pos < len(noise):
        t_s = float(t_ns - t0_ns) / 1e9 if ns_clock else time
        if t_s >= pc[C_DURATION]:
            break
        n, sp = profile_at(prof_n, prof_sp, pc[C_DT], t_s)
        ts = 120.0 / (pc[C_NCYL] * n)
        w = noise[pos]
        p, t = st[3], st[4]
        r = rows[k]
        times[k] = t_ns
        r[R_T], r[R_TS], r[R_N], r[R_SP] = time, ts, n, sp
        r[R_Y], r[R_Y + 1], r[R_Y + 2] = measure(st, w, pc)
        for j in range(6):
            r[R_X + j] = st[j]
        r[R_MDOT_AT] = throttle_flow_of(st[1], p, pc[C_PA], pc[C_TA], c, cd_alpha, cd_table,
                                        prs)[0]
        r[R_MDOT_AC] = port_flow_of(n, p, t, c, eta_rpm, eta_val)
        r[R_CAC] = air_charge_of(n, p, t, c, pc[C_VCYL], eta_rpm, eta_val)
        r[R_M] = plant_step(st, sp, n, pc[C_PA], pc[C_TA], pc[C_TCOOL], ts, w, pc, c, cd_alpha,
                            cd_table, prs, eta_rpm, eta_val)
        pos += 1
        step_ns = round(ts * 1e9)
        t_ns += step_ns if step_ns > 1 else 1
        time += ts
        k += 1
    return k, t_ns, time, pos


@dataclass(frozen=True)
class ManifoldTrace:
    """One simulated run, one entry per event n (state and measurements before the step)."""

    t: np.ndarray  # event time, s
    ts: np.ndarray  # event period T_s used for the step, s
    n_rpm: np.ndarray
    ta_sp: np.ndarray  # rad
    x: np.ndarray  # (events, 6) augmented state
    y: np.ndarray  # (events, 3) measurements TA, P_im, T_im.out
    mdot_at: np.ndarray  # kg/s
    mdot_ac: np.ndarray  # kg/s
    cac: np.ndarray  # kg per cylinder event
    substeps: np.ndarray


def simulate(profile: DriveProfile, seed: int = 0, params: ManifoldParams = V8_5L7,
             config: ManifoldPlantConfig = ManifoldPlantConfig()) -> ManifoldTrace:
    """Run the plant event by event over the profile (truth_events on the float clock),
    starting at rest at its first point."""
    rng = rng_streams(seed, ("manifold.plant",))["manifold.plant"]
    n0, sp0 = profile.at(0.0)
    x0 = steady_state_vector(nominal_input(sp0, n0, params), params)
    prof_n, prof_sp = profile_arrays(profile)
    cap = int(profile.duration_s / sample_time(float(prof_n.max()), params.n_cyl)) + 2
    block = config.block
    noise = rng.standard_normal((-(-cap // block) * block, 7))  # as EventsAhead draws them
    pc = plant_constants(params, config, profile.duration_s, profile.dt_s)
    rows = np.empty((cap, N_ROW))
    k, _, time, _ = truth_events(np.asarray(x0, dtype=np.float64), 0, 0, 0.0, False, prof_n,
                                 prof_sp, noise, 0, pc, *tables(params),
                                 np.empty(cap, dtype=np.int64), rows)
    assert time >= profile.duration_s, "simulate: more events than the fastest speed allows"
    a = rows[:k]
    return ManifoldTrace(
        t=a[:, R_T].copy(), ts=a[:, R_TS].copy(), n_rpm=a[:, R_N].copy(),
        ta_sp=a[:, R_SP].copy(), x=a[:, R_X:R_X + 6].copy(), y=a[:, R_Y:R_Y + 3].copy(),
        mdot_at=a[:, R_MDOT_AT].copy(), mdot_ac=a[:, R_MDOT_AC].copy(), cac=a[:, R_CAC].copy(),
        substeps=a[:, R_M].astype(int),
    )


def profile_arrays(profile: DriveProfile) -> tuple[np.ndarray, np.ndarray]:
    """A drive profile's (N, TA_SP) grid as the kernels read it (profile_at); ValueError for
    one they cannot: fewer than two points, or an engine speed that is not positive."""
    prof_n = np.ascontiguousarray(profile.n_rpm, dtype=np.float64)
    n_min = float(prof_n.min()) if len(prof_n) else math.nan
    if len(prof_n) < 2 or not (math.isfinite(n_min) and n_min > 0.0):
        raise ValueError("manifold drive profile: at least two points, engine speeds > 0 rpm")
    return prof_n, np.ascontiguousarray(profile.ta_sp, dtype=np.float64)


def plant_constants(params: ManifoldParams, config: ManifoldPlantConfig, duration_s: float,
                    dt_s: float) -> np.ndarray:
    """The kernels' plant constants vector (pc) for a DriveProfile of that duration and
    grid."""
    s = config.noise_scale
    q, r = config.noise.q_diag(), config.noise.r_diag()
    g = config.sensor_gains
    pc = np.array([params.zeta, params.omega0, params.tau_temp_s, params.v_cyl_dm3,
                   float(params.n_cyl), params.p_a_kpa, params.t_a_k, params.t_cool_k,
                   *(s * math.sqrt(q[i]) for i in (1, 3, 4, 5)), *(s * math.sqrt(v) for v in r),
                   g[0], g[1], g[2], P_MIN_KPA, P_MAX_KPA, T_MIN_K, T_MAX_K, duration_s, dt_s],
                  dtype=np.float64)
    assert len(pc) == N_PLANT_CONSTS
    return pc


_PART_COLUMNS = [R_N, R_SP, R_Y, R_Y + 1, R_Y + 2, R_X + 3, R_X + 4, R_CAC]


class EventsAhead:
    """The truth's events for vecu.plant.node.ManifoldPart, computed ahead in blocks by
    truth_events on its integer-nanosecond clock, the noise drawn as simulate draws it (the
    plant depends on nothing the ECU sends)."""

    AHEAD = 256  # events per kernel call (~1.3 s of driving at 2000 rpm)

    def __init__(self, params: ManifoldParams, config: ManifoldPlantConfig,
                 rng: np.random.Generator, x0: np.ndarray) -> None:
        self.params, self.config = params, config
        self._rng = rng
        self.state = np.array(x0, dtype=np.float64)
        self._tables = tables(params)
        self._noise = np.empty((0, 7))
        self._pos = 0
        self._prof: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.times = np.zeros(self.AHEAD, dtype=np.int64)
        self._rows = np.zeros((self.AHEAD, N_ROW))
        self.out = self._rows[:, _PART_COLUMNS]
        self.next_ns = 0

    def start_profile(self, profile: DriveProfile) -> None:
        self._prof = (*profile_arrays(profile),
                      plant_constants(self.params, self.config, profile.duration_s,
                                      profile.dt_s))

    def fill(self, t_ns: int, t0_ns: int) -> int:
        """Compute the events from t_ns (the profile started at t0_ns) into times / out (N,
        TA_SP, the three readings, the truth's P_im, T_im and CAC); returns how many (0: the
        profile ends before t_ns, start the next one)."""
        assert self._prof is not None
        prof_n, prof_sp, pc = self._prof
        while True:
            if self._pos >= len(self._noise):
                self._noise = self._rng.standard_normal((self.config.block, 7))
                self._pos = 0
            k, self.next_ns, _, self._pos = truth_events(
                self.state, t_ns, t0_ns, 0.0, True, prof_n, prof_sp, self._noise, self._pos, pc,
                *self._tables, self.times, self._rows)
            if k > 0 or self._pos < len(self._noise):
                self.out = self._rows[:, _PART_COLUMNS]
                return k
