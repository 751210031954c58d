"""Adaptive manifold EKF: the paper's augmented model (eq. 10) plus a slowly varying
volumetric-efficiency correction c, eta_true(N, P) = c * eta_calibrated(N, P) (vecu decision,
docs/models.md "Adaptive air charge").

State x = (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas, c), c a random walk with variance
`q_eta` per event, bounded to `eta_box`. The event map is the EKF's (manifold_model.f with the
event integrator) with the eta_N(N) table scaled by c (eta is linear in that table); F gets one
more column, d(P, T)_{n+1}/dc by a one-sided difference of the integrator, and F[6, 6] = 1.
What identifies c: at a steady state only the ratio of throttle flow to port flow shows in P_im
(eta and C_d A_th errors are confounded there: c absorbs both, and a P_im gain error); the speed
of the pressure transients (pumping time constant, proportional to 1/eta) separates them. The
CAC and its 6-event prediction use c * eta (cac_predict's eta_scale).

The whole event is one kernel (`adaptive_event`, compiled under numba; its Python function under
the python backend). An event the kernel cannot decide (S not positive definite) or a divergence
resets the filter (counted), c back to 1 with its prior variance.
"""

from __future__ import annotations

import math

import numpy as np

from vecu.estimators.manifold.adaptive_kernel import N_XA, adaptive_event, prepare
from vecu.estimators.manifold.filters import ManifoldFilterConfig, _ManifoldKF
from vecu.estimators.manifold.kernels import (
    DIVERGED,
    FALLBACK,
    filter_constants,
    numba_tables,
)
from vecu.estimators.manifold.model import ALPHA_SDC_MIN, FD_ALPHA, FD_REL, q_matrix
from vecu.models.manifold_params import EngineInput

ETA_FD = 1e-6  # finite-difference step in c


class ManifoldAdaptive(_ManifoldKF):
    """The adaptive EKF (see module). eta_scale / eta_sigma: c and its standard deviation."""

    name = "adaptive"

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),  # noqa: B008
                 x0: np.ndarray | None = None) -> None:
        super().__init__(config, None if x0 is None else np.asarray(x0, dtype=float)[:6])
        c = config
        self.Q = np.zeros((N_XA, N_XA))
        self.Q[:6, :6] = q_matrix(c.noise)
        self.Q[6, 6] = self.Q[7, 7] = c.eta_q
        self._P0 = np.diag(np.array((*c.p0_diag, c.eta_p0, c.eta_p0), dtype=float))
        self._x_default = np.append(self._x_default[:6], (1.0, 1.0))
        tables = numba_tables(self.params)
        if tables is None:
            raise ValueError("the adaptive manifold filter needs kappa > 1, pr_reg <= 1 and "
                             "p_exh >= 0 (the compiled integrator's domain)")
        self._args = (filter_constants(c, ALPHA_SDC_MIN), self.Q, np.array([FD_ALPHA, FD_REL]),
                      np.array([c.eta_box[0], c.eta_box[1], ETA_FD, c.eta_pr_freeze,
                                c.eta_alpha_gate]), *tables)
        self.reset(count=False)

    @property
    def eta_scale(self) -> float:
        """c of the posterior: eta_true / eta_calibrated."""
        return float(self.x_post[6])

    @property
    def eta_sigma(self) -> float:
        return float(math.sqrt(max(float(self.P_post[6, 6]), 0.0)))

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        run = adaptive_event.impl()
        if run is not adaptive_event.py:
            prepare()
        mask = 0
        for i in chans:
            mask |= 1 << i
        ly = self._last_y
        gr = self._gated_run
        xo = np.empty((3, N_XA))
        Po = np.empty((2, N_XA, N_XA))
        a = self._args
        try:
            code = run(self.x, self.P, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts,
                       ly[0], ly[1], ly[2], mask, gr[0], gr[1], gr[2], a[0], a[1], a[2], a[3],
                       *a[4:])
        except (FloatingPointError, ValueError, ZeroDivisionError, IndexError, OverflowError,
                np.linalg.LinAlgError):
            code = DIVERGED
        if code & (FALLBACK | DIVERGED):
            self._reset_in_step()
            return
        for i in chans:
            if code >> i & 1:
                self.gated[i] += 1
                gr[i] += 1
            else:
                gr[i] = 0
        self.x, self.x_post = xo[0], xo[1]
        self.P, self.P_post = Po[0], Po[1]
        self.last_prediction = (u, xo[2])

    def _block_ready(self) -> bool:
        if not self._initialised or adaptive_event.impl() is adaptive_event.py:
            return False
        prepare()
        if self._kernel_args is None:
            self._kernel_args = self._args
            self._kernel_args_ready = True
        return True
