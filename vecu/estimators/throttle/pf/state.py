"""The throttle particle filter's state: one record with named fields (STATE, all float64, in the
vector `new_state`, viewed by name with `state_of`: a numpy record compiled, a ctypes StateView
in Python; docs/models.md, "Production throttle estimator"), and the particle Banks, one
(3, 7, n) array per particle count.
"""

from __future__ import annotations

import ctypes
import weakref
from typing import Any

import numpy as np

from vecu.kernels import kernel

OFFSET_BLOCK = 4096  # window offsets of the normal table drawn per refill

_F = "f8"
STATE: Any = np.dtype([
    # the particle set: theta extent (hi: 90 once lo is in mode 3), weight sums w, w^2
    ("lo", _F), ("hi", _F), ("sw", _F), ("sw2", _F),
    ("gated", _F),  # outliers rejected in a row
    ("steps", _F),  # ticks so far
    ("ksteps", _F),  # Kalman-stretch ticks so far
    ("cur", _F),  # which of a bank's two frames holds the particles (0 / 1)
    ("in_kf", _F),  # 1 during a Kalman stretch
    ("target", _F),  # RESAMPLE: the particle count to resample into
    ("koff", _F),  # next unused entry of offs
    ("o1", _F),  # the tick's first window offset (a hand-over from the Kalman filter draws there)
    # configuration: Kalman stretches allowed, checked every kf_every ticks, entered when all
    # theta are in (kf_enter[0], kf_enter[1]) and all i > kf_enter[2]
    ("use_kf", _F), ("kf_every", _F), ("kf_enter", _F, 3),
    # n_low particles while some theta is below low_enter, n_high once all are above low_exit
    ("n_low", _F), ("n_high", _F), ("low_enter", _F), ("low_exit", _F),
    # the reported std: x inflation; + lock_var while theta <= lock_below with u > lock_u
    ("inflation", _F), ("lock_below", _F), ("lock_var", _F), ("lock_u", _F),
    # the particle step's constants (pf.update): eq. 4 linearised, the class bounds and b
    ("y_shift", _F), ("inv_c2", _F), ("kappa", _F), ("neg_k2", _F), ("neg_four_s2", _F),
    ("clip_lo", _F), ("clip_hi", _F), ("class_b", _F, 4), ("bounds", _F, 3),
    # the Kalman stretch (pf.kalman_stretch): x = (th, rh, ci, p00, p01, p02, p11, p12, p22),
    # eq. 3's class-3 row coefficients, (q_th, q_i, R, gate), (lo_deg, top_sigmas, i_min, infl)
    ("kf_x", _F, 9), ("kf_coef", _F, 15), ("kf_prm", _F, 4), ("kf_cfg", _F, 4),
    ("offs", _F, 2 * OFFSET_BLOCK),  # window offsets (pairs: theta noise, current noise)
])


class StateView(ctypes.Structure):
    """STATE in Python: its scalar fields as ctypes doubles, its array fields numpy views of the
    same memory (set by new_state)."""

    _fields_ = [(name, ctypes.c_double) if not STATE.fields[name][0].shape
                else (f"_{name}", ctypes.c_double * STATE.fields[name][0].shape[0])
                for name in STATE.names]
    kf_enter: np.ndarray
    class_b: np.ndarray
    bounds: np.ndarray
    kf_x: np.ndarray
    kf_coef: np.ndarray
    kf_prm: np.ndarray
    kf_cfg: np.ndarray
    offs: np.ndarray


_views: dict[int, Any] = {}  # id(S) -> weak reference to its StateView


def new_state() -> tuple[np.ndarray, Any]:
    """A zeroed state: (its float64 vector S, the StateView of S; state_of(S) is that view
    in Python, alive as long as the caller keeps it)."""
    S = np.zeros(STATE.itemsize // 8)
    s = StateView.from_buffer(S)  # type: ignore[arg-type]
    r = S.view(STATE)[0]
    s.kf_enter, s.class_b, s.bounds = r["kf_enter"], r["class_b"], r["bounds"]
    s.kf_x, s.kf_coef, s.kf_prm, s.kf_cfg = r["kf_x"], r["kf_coef"], r["kf_prm"], r["kf_cfg"]
    s.offs = r["offs"]
    _views[id(S)] = weakref.ref(s)
    weakref.finalize(s, _views.pop, id(S), None)
    return S, s


def _state_view(S: Any) -> Any:
    return _views[id(S)]()


@kernel(python=_state_view)
def state_of(S: Any) -> Any:
    """The record STATE viewing the float vector S (the same memory; in Python its StateView,
    see the module)."""
    return S.view(STATE)[0]


class Frame:
    """One particle set. F rows: theta, rho, i, 1, sgn(rho), theta^2, weight (named views)."""

    def __init__(self, F: np.ndarray) -> None:
        self.F = F
        F[3] = 1.0
        F[6] = 1.0
        self.th, self.rh, self.ci, self.one, self.sg, self.th2, self.w = F
        self.top3 = F[:3]


class Bank:
    """The buffers of one particle count n: FB holds frames 0 and 1 and the scratch rows (2);
    s.cur (the filter's state, shared by its banks) says which frame holds the particles."""

    def __init__(self, n: int, s: Any) -> None:
        self.n = n
        self.FB = np.zeros((3, 7, n))
        self.frames = (Frame(self.FB[0]), Frame(self.FB[1]))
        self._s = s

    @property
    def cur(self) -> Frame:
        """The frame holding the particles."""
        return self.frames[int(self._s.cur)]

    @property
    def nxt(self) -> Frame:
        """The other frame (a step writes there)."""
        return self.frames[1 - int(self._s.cur)]
