"""5.7 L V8 intake manifold and electronic throttle parameters for Dutka 2006's eq. 1-9 and
Section IV noise (the paper gives no engine numbers: each value is commented with its source),
in the model's units (docs/models.md, "Intake manifold › Units, Parameters").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class ManifoldParams:
    """Engine, throttle and manifold constants (tables as tuples: the dataclass stays hashable)."""

    # Gas: ratio of specific heats and gas constant of dry air (eq. 2-6; manifold.md table).
    kappa: float = 1.4
    r_air: float = 287.0  # J/(kg K)
    # Displacement V_d and cylinder count; V_cyl = V_d / n_cyl is the per-event volume in eq. 5-6
    # (manifold.md: the pumping term uses V_d/8, not V_d). eq. 8 uses V_d itself.
    v_d_dm3: float = 5.7
    n_cyl: int = field(default=8, metadata={"bounds": (1, 16)})  # vecu params --set bounds
    v_im_dm3: float = 5.0  # intake manifold volume V_im (manifold.md)
    # Throttle body: bore 75 mm, A_th = pi R^2 (1 - cos alpha) (eq. 4; R from manifold.md).
    r_th_m: float = 0.0375
    alpha_max_rad: float = math.pi / 2  # wide-open stop: the flow area saturates here (ours, docs)
    # Actuator, 2nd-order continuous model behind eq. 1 (manifold.md: omega0 50 rad/s, zeta 0.8).
    omega0: float = 50.0  # rad/s
    zeta: float = 0.80
    # Discharge coefficient C_d(pr, alpha) lookup (eq. 2-3 text: "modeled by the lookup table").
    # manifold.md fixes only the ends, 0.60 closed and 0.86 wide open at pr -> 1; the shape between
    # is ours: rising with the opening, +0 .. +0.02 from pr = 0.5 to pr = 1, flat below pr = 0.5.
    cd_alpha_deg: tuple[float, ...] = (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0)
    cd_pr: tuple[float, ...] = (0.0, 0.5, 1.0)
    cd_table: tuple[tuple[float, ...], ...] = (
        (0.60, 0.66, 0.71, 0.75, 0.79, 0.82, 0.84),  # pr = 0.0
        (0.60, 0.66, 0.71, 0.75, 0.79, 0.82, 0.84),  # pr = 0.5
        (0.60, 0.67, 0.73, 0.77, 0.81, 0.84, 0.86),  # pr = 1.0
    )
    # Regularisation of eq. 2 near pr = 1 (manifold.md: "linear for pr > 0.98"); we use the C1
    # quadratic in (1 - pr) through psi(0.98) with matching slope (docs/models.md).
    pr_reg: float = 0.98
    # Volumetric efficiency eta(N, P) = eta_N(N) (r_c - (P_exh/P)^(1/kappa)) / (r_c - 1)
    # (manifold.md; the pressure factor is the residual-gas expansion term).
    r_c: float = 10.1  # compression ratio (manifold.md)
    p_exh_kpa: float = 105.0  # exhaust back-pressure (manifold.md)
    # eta_N(N): anchors 0.74 @ 500, 0.92 @ 3500-4000, 0.81 @ 6500 rpm (manifold.md); values in
    # between are our smooth interpolation of those anchors.
    eta_n_rpm: tuple[float, ...] = (
        500.0, 1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0, 4000.0, 4500.0, 5000.0, 5500.0,
        6000.0, 6500.0,
    )
    eta_n_val: tuple[float, ...] = (
        0.74, 0.79, 0.84, 0.875, 0.90, 0.915, 0.92, 0.92, 0.91, 0.89, 0.865, 0.84, 0.81,
    )
    # Heat transfer Q_ext = h1 (T_cool - T_im) + h2 (T_a - T_im) (eq. 5-6 text; values manifold.md).
    h1_w_per_k: float = 10.0  # from the engine (coolant)
    h2_w_per_k: float = 20.0  # from ambient
    tau_temp_s: float = 8.0  # IAT sensor time constant tau_Temp (eq. 9; manifold.md)
    # Nominal external conditions (the paper takes them from the US06 log; manifold.md values).
    p_a_kpa: float = 100.0
    t_a_k: float = 298.15
    t_cool_k: float = 363.15
    # Idle / decel throttle floor 7.5 deg + 14.5 deg (N - 700)/5300 (manifold.md).
    floor_deg: float = 7.5
    floor_span_deg: float = 14.5
    n_idle_rpm: float = 700.0
    n_max_rpm: float = 5600.0
    # Integration (ours, docs/models.md): sub-steps per event so that dt * lambda <= lam_dt_max
    # and the state moves at most dp/dt_step_max per sub-step; at most max_substeps
    # (manifold.md: dt lambda <= 1, M <= 40).
    lam_dt_max: float = 1.0
    dp_step_max_kpa: float = 0.5  # largest P_im change per sub-step (accuracy in fast transients)
    dt_step_max_k: float = 0.5  # largest T_im change per sub-step
    max_substeps: int = field(default=40, metadata={"bounds": (1, 1000)})  # a bounded event cost

    @property
    def v_cyl_dm3(self) -> float:
        """Displacement of one cylinder, V_d / n_cyl (the per-event volume of eq. 5-6)."""
        return self.v_d_dm3 / self.n_cyl


    def throttle_floor_rad(self, n_rpm: float) -> float:
        """Idle/decel throttle floor (manifold.md), rad; N clamped to [n_idle, n_max]."""
        n = min(max(n_rpm, self.n_idle_rpm), self.n_max_rpm)
        frac = (n - self.n_idle_rpm) / (self.n_max_rpm - self.n_idle_rpm)
        return math.radians(self.floor_deg + self.floor_span_deg * frac)


@dataclass(frozen=True)
class ManifoldNoise:
    """Covariances of Section IV, per event, in the model's units (rad^2, kPa^2, K^2).

    Q = diag(cov w_ET, cov w_IM, cov w_im.meas); R = diag(cov v_ET, cov v_IM, cov v_im.meas).
    R_TA = 7.62e-5 rad^2 is sigma ~ 0.5 deg (manifold.md: rad^2, not deg^2).
    """

    q_et: tuple[float, float, float] = (0.0, 1.95e-6, 0.0)  # Section IV, rad^2
    q_im: tuple[float, float] = (2.5e-3, 1e-2)  # Section IV, (kPa^2, K^2)
    q_tmeas: float = 1e-4  # Section IV, K^2
    r_ta: float = 7.62e-5  # Section IV, rad^2
    r_pim: float = 1e-2  # Section IV, kPa^2
    r_tim: float = 2.5e-3  # Section IV, K^2

    def q_diag(self) -> tuple[float, ...]:
        """Diagonal of Q for the 6-state augmented model (x_ET, P_im, T_im, T_im.meas)."""
        return (*self.q_et, *self.q_im, self.q_tmeas)

    def r_diag(self) -> tuple[float, float, float]:
        """Diagonal of R for y = (TA, P_im, T_im.out)."""
        return (self.r_ta, self.r_pim, self.r_tim)


V8_5L7 = ManifoldParams()
PAPER_NOISE = ManifoldNoise()


@dataclass(frozen=True)
class EngineInput:
    """Inputs at one event: setpoint TA_SP (rad), N (rpm), P_a (kPa), T_a and T_coolant (K)."""

    ta_sp: float
    n_rpm: float
    p_a: float = V8_5L7.p_a_kpa
    t_a: float = V8_5L7.t_a_k
    t_cool: float = V8_5L7.t_cool_k
