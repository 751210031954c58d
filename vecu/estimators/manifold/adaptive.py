"""Adaptive manifold EKF: eq. 10 plus slowly varying parameters c, c_th, g, k_zeta, k_omega
(Schmidt consider updates, spike-and-slab c_used; docs/models.md, "Adaptive air charge"). The
event is one kernel (adaptive_event); an undecidable event or a divergence resets (counted).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.manifold.adaptive_event import N_XA, adaptive_event
from vecu.estimators.manifold.event import (
    ALPHA_SDC_MIN,
    DIVERGED,
    FD_ALPHA,
    FD_REL,
    filter_constants,
)
from vecu.estimators.manifold.filters import ManifoldFilterConfig, _ManifoldKF
from vecu.estimators.manifold.model import q_matrix
from vecu.models.manifold_integrator import tables
from vecu.models.manifold_params import EngineInput

ETA_FD = 1e-6  # finite-difference step in c
ACT_FD = 1e-6  # ... in k_zeta, k_omega


def eta_scale_used(c: Any, var: Any, p_drift: float, slab_sd: float) -> Any:
    """The eta scale the CAC uses: the posterior mean of c under a spike-and-slab prior, the
    engine is the calibrated one (c = 1) with probability 1 - p_drift, otherwise c ~ N(1,
    slab_sd^2); the filter's c with variance var stands for the measurement of c (its prior is
    broad). Bayes factor B = N(c; 1, var + s^2) / N(c; 1, var), w = p B / (p B + 1 - p),
    result 1 + w s^2 / (s^2 + var) (c - 1). Arrays or floats."""
    c = np.asarray(c, dtype=float)
    v = np.maximum(np.asarray(var, dtype=float), 1e-12)
    s2 = slab_sd * slab_sd
    d2 = (c - 1.0) ** 2
    log_b = 0.5 * np.log(v / (v + s2)) + 0.5 * d2 * (1.0 / v - 1.0 / (v + s2))
    if p_drift <= 0.0:
        w = np.zeros_like(c)
    elif p_drift >= 1.0:
        w = np.ones_like(c)
    else:
        log_odds = np.clip(log_b + math.log(p_drift / (1.0 - p_drift)), -700.0, 700.0)
        w = 1.0 / (1.0 + np.exp(-log_odds))
    out = 1.0 + w * s2 / (s2 + v) * (c - 1.0)
    return float(out) if out.ndim == 0 else out


class ManifoldAdaptive(_ManifoldKF):
    """The adaptive EKF (see module): c is x_post[6], its variance P_post[6, 6]."""

    name = "adaptive"

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                 x0: np.ndarray | None = None) -> None:
        super().__init__(config, None if x0 is None else np.asarray(x0, dtype=float)[:6])
        c = config
        self.Q = np.zeros((N_XA, N_XA))
        self.Q[:6, :6] = q_matrix(c.noise)
        self.Q[6, 6] = self.Q[7, 7] = c.eta_q
        self.Q[8, 8] = self.Q[9, 9] = self.Q[10, 10] = c.act_q
        self._P0 = np.diag(np.array((*c.p0_diag, c.eta_p0, c.eta_p0, c.ta_gain_p0, c.act_p0,
                                     c.act_p0), dtype=float))
        self._x_default = np.append(self._x_default[:6], (1.0, 1.0, 1.0, 1.0, 1.0))
        self._kargs = (filter_constants(c, ALPHA_SDC_MIN), self.Q, np.array([FD_ALPHA, FD_REL]),
                      np.array([c.eta_box[0], c.eta_box[1], ETA_FD, c.eta_pr_freeze,
                                c.eta_alpha_gate, *c.ta_gain_box, *c.act_box, ACT_FD]),
                      *tables(self.params))
        self.reset(count=False)

    def eta_used(self, c: Any, var: Any) -> Any:
        """eta_scale_used with this filter's eta_drift_prior and eta_slab_sd."""
        return eta_scale_used(c, var, self.config.eta_drift_prior, self.config.eta_slab_sd)

    # the event: filters._ManifoldKF._event around adaptive_event; no jittered fallback (an
    # event the kernel cannot decide resets the filter) and no gated counts on a reset
    _count_gated_on_reset = False
    _EVENT_ERRORS = (FloatingPointError, ValueError, ZeroDivisionError, IndexError, OverflowError,
                     np.linalg.LinAlgError)

    _KERNELS = (adaptive_event, None)
    _KIND = 2  # filter_events' kind

    def _fallback(self, finish: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                  u: EngineInput, ts: float, mask: int, code: int) -> int:
        return DIVERGED
