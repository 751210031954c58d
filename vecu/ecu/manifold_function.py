"""ECU manifold function: intake manifold state and cylinder air charge per engine event
(Dutka 2006).

Each engine event brings ENG_Event and ENG_Intake (same counter). On the next 1 ms base tick
the function runs its filter (the live SDKF: one warm-started Riccati iteration per event, or
the EKF) once per complete event, predicts the cylinder air charge 6 events ahead with the
setpoint held (the ECU does not know future pedal positions), and sends ECU_ManifoldEstimate.
The filter does all three (filter.estimate): the usual SDKF / EKF event in one kernel call, the
adaptive filter and any unusual event (a missing or rejected reading, a fallback, a reset) in
separate calls, with the same numbers.
Before each ECU_ManifoldEstimate the function sends ECU_ManifoldSigma: the event's counter, the
validity (vecu.ecu.validity; UDS DID 0x020F: init until the filter has been initialised from a
complete event, degraded for an event with a reading missing, rejected or gated) and the
one-sigma uncertainties (throttle angle, P_im, T_im from the filter's reported covariance,
reported_cov(): P_n|n scaled for consistency; the CAC and its 6-event prediction from it by
cac_predict.cac_sigmas).
Events whose frames did not both arrive are counted as lost; the filter predicts through them.
An event whose input the filter cannot use (engine speed outside `kf.n_range`, e.g. 0 rpm, which
the DBC allows) is refused when it arrives: counted in `implausible_inputs` (and by the node as an
rx value error), logged once per burst, never filtered; the event counts as lost.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from vecu.clock import NS_PER_MS, NS_PER_S, Stopwatch
from vecu.codec import DbcCodec
from vecu.ecu.diagnostics import FLOAT, UBYTE, ULONG, Did, Reader, Variable, validity_did
from vecu.ecu.node import Send, Subscription
from vecu.ecu.validity import DEGRADED, INIT, VALID
from vecu.estimators.manifold.cac_predict import HORIZON, cac_sigmas
from vecu.estimators.manifold.factory import make_filter
from vecu.estimators.manifold.filters import ManifoldFilterConfig, input_problem
from vecu.models.manifold import nominal_input
from vecu.models.manifold_params import EngineInput
from vecu.units import KELVIN_AT_0_DEGC, MG_PER_KG, RAD_PER_DEG

log = logging.getLogger(__name__)
MAX_BURSTS_LOGGED = 20  # bursts of refused engine events logged (all are counted)


@dataclass(frozen=True)
class ManifoldFunctionConfig:
    """The ECU's manifold calibration: which filter, and the engine and noise it believes in
    (`kf.params`, `kf.noise`; equal to the simulated engine unless a study sets them apart)."""

    filter: str = "sdkf"  # "sdkf" (live, one Riccati iteration per event), "ekf" or "adaptive"
    kf: ManifoldFilterConfig = field(default_factory=ManifoldFilterConfig)


class ManifoldFunction:
    name = "manifold"
    period_ns = NS_PER_MS  # polls for complete events every base tick

    def __init__(self, codec: DbcCodec,
                 config: ManifoldFunctionConfig = ManifoldFunctionConfig(),
                 stopwatch: Stopwatch | None = None) -> None:
        """stopwatch times the filter and the prediction (filter_seconds, predict_seconds).
        The usual event (SDKF / EKF) runs the filter, the CAC and its prediction in one kernel
        call (filter.estimate): that time goes into filter_seconds, and predict_seconds counts
        only the events that made separate calls."""
        self.filter = make_filter(config.filter, config.kf)
        self.filter_name = config.filter
        self._engine = self.filter.params  # the calibration: filter, CAC and prediction
        self._kf = config.kf
        self._out_frame = codec["ECU_ManifoldEstimate"].framer((
            "MFD_ThrottleAngle", "MFD_Pressure", "MFD_Temperature", "MFD_CAC", "MFD_CACPred6"))
        # the adaptive filter's corrections (ECU_ManifoldAdapt), sent only with that filter
        self._adapt_frame = codec["ECU_ManifoldAdapt"].framer((
            "MFD_EtaCorr", "MFD_EtaCorrStd", "MFD_FlowCorr", "MFD_TaGainCorr", "MFD_ActZetaCorr",
            "MFD_ActOmegaCorr")) if config.filter == "adaptive" else None
        self._sigma_frame = codec["ECU_ManifoldSigma"].framer((
            "MFD_EventCounter", "MFD_Validity", "MFD_ThrottleAngleStd", "MFD_PressureStd",
            "MFD_TemperatureStd", "MFD_CACStd", "MFD_CACPred6Std"))
        self.validity = INIT
        # the last event's sigmas: throttle angle (rad), P_im (kPa), T_im (K), CAC, CAC+6 (kg)
        self.sigmas: tuple[float, float, float, float, float] | None = None
        self.timeouts = 0
        self.estimates_sent = 0
        self.events = 0          # complete events filtered
        self.lost_events = 0     # counter gaps (frames lost or rejected)
        self.implausible_inputs = 0  # ENG_Event frames refused (engine speed outside n_range...)
        self.estimator_faults = 0    # non-finite CAC outputs caught here (should stay 0)
        self._refused_in_row = 0
        self._bursts_logged = 0
        self.filter_seconds = 0.0   # time in the filter step (with the CAC: see above)
        self.predict_seconds = 0.0  # time in the CAC and its 6-event prediction apart
        self._watch = stopwatch if stopwatch is not None else Stopwatch()
        self._event: tuple[dict[str, float], EngineInput] | None = None
        self._iat: tuple[int, float] | None = None
        self._last_counter: int | None = None
        # last outputs, read by probes: (absolute event index, P kPa, T K, CAC kg, CAC+6 kg)
        self.last: tuple[int, float, float, float, float] | None = None
        self._abs_index = -1

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("ENG_Event", self._on_event), Subscription("ENG_Intake", self._on_iat)]

    def _on_event(self, values: dict[str, float], t_ns: int) -> str | None:
        u = nominal_input(values["ENG_ThrottleSetpoint"] * RAD_PER_DEG, values["ENG_Speed"],
                          self._engine)
        problem = input_problem(u, self._kf)
        if problem is not None:  # refused: the filter, the CAC and the prediction never see it
            self.implausible_inputs += 1
            self._refused_in_row += 1
            if self._refused_in_row == 1 and self._bursts_logged < MAX_BURSTS_LOGGED:
                self._bursts_logged += 1  # bounded: hostile and good frames interleaved
                log.warning("ecu manifold: engine event %d refused: %s (further ones counted, "
                            "logged again after a plausible event%s)",
                            int(values["ENG_EventCounter"]), problem,
                            "; the last such burst logged" if self._bursts_logged
                            == MAX_BURSTS_LOGGED else "")
            return problem
        if self._refused_in_row:
            if self._bursts_logged < MAX_BURSTS_LOGGED:
                log.info("ecu manifold: plausible engine events again after %d refused",
                         self._refused_in_row)
            self._refused_in_row = 0
        self._event = (values, u)
        return None

    def _on_iat(self, values: dict[str, float], t_ns: int) -> None:
        self._iat = (int(values["ENG_IntakeCounter"]), values["ENG_IAT"] + KELVIN_AT_0_DEGC)

    def run(self, t_ns: int, send: Send) -> None:
        event, iat = self._event, self._iat
        if event is None:
            return
        self._event = None
        ev, u = event
        counter = int(ev["ENG_EventCounter"])
        if self._last_counter is not None:
            gap = (counter - self._last_counter) % 256
            self.lost_events += max(gap - 1, 0)
            self._abs_index += max(gap, 1)
        else:
            self._abs_index = counter
        self._last_counter = counter
        flt = self.filter
        ta, map_kpa = ev["ENG_ThrottleAngle"] * RAD_PER_DEG, ev["ENG_MAP"]
        # a missing IAT reading is a NaN channel: rejected, the others used
        t_meas = iat[1] if iat is not None and iat[0] == counter else math.nan
        watch = self._watch
        troubles = flt.missing + sum(flt.rejected) + sum(flt.gated)
        watch.lap()
        x, cac, cac6, scale, filter_s, predict_s = flt.estimate(ta, map_kpa, t_meas, u, HORIZON,
                                                                watch.lap)
        self.filter_seconds += filter_s
        self.predict_seconds += predict_s
        if not (math.isfinite(cac) and math.isfinite(cac6)):  # last line of defence
            self.estimator_faults += 1
            flt.reset()
            return
        self.events += 1
        self.last = (self._abs_index, x[3], x[4], cac, cac6)
        P = flt.reported_cov()  # the consistent sigmas (issue 30; docs/models.md)
        s_cac, s_cac6 = cac_sigmas(flt.x_post, P, flt.Q, u, self._engine, HORIZON, scale)
        sd = [math.sqrt(max(float(P[i, i]), 0.0)) for i in (1, 3, 4)]
        self.sigmas = (sd[0], sd[1], sd[2], s_cac, s_cac6)
        self.validity = validity = (
            INIT if not flt.initialised else
            DEGRADED if flt.missing + sum(flt.rejected) + sum(flt.gated) != troubles else VALID)
        ts = t_ns / NS_PER_S
        send(*self._sigma_frame(ts, counter, validity, sd[0] / RAD_PER_DEG, sd[1], sd[2],
                               s_cac * MG_PER_KG, s_cac6 * MG_PER_KG))
        self.estimates_sent += send(*self._out_frame(
            ts, x[1] / RAD_PER_DEG, x[3], x[4] - KELVIN_AT_0_DEGC, cac * MG_PER_KG,
            cac6 * MG_PER_KG))
        if self._adapt_frame is not None:
            sigma = math.sqrt(max(float(flt.P_post[6, 6]), 0.0))
            self.estimates_sent += send(*self._adapt_frame(
                ts, 100.0 * (scale - 1.0), 100.0 * sigma, 100.0 * (x[7] - 1.0),
                100.0 * (x[8] - 1.0), 100.0 * (x[9] - 1.0), 100.0 * (x[10] - 1.0)))

    def status_signals(self) -> dict[str, int]:
        return {}

    def _last(self, i: int, scale: float = 1.0, offset: float = 0.0) -> Reader:
        """Element i of the last event's output (None before the first), scaled."""
        return lambda: None if self.last is None else self.last[i] * scale + offset

    def dids(self) -> list[Did]:
        """UDS: the last event's P_im, T_im, CAC and 6-event CAC prediction."""
        last = self._last
        return [
            Did(0x0200, "manifold pressure", "H", 0.01, "kPa", last(1)),
            Did(0x0201, "manifold temperature", "h", 0.01, "degC",
                last(2, offset=-KELVIN_AT_0_DEGC)),
            Did(0x0202, "cylinder air charge", "H", 0.1, "mg", last(3, MG_PER_KG)),
            Did(0x0203, "cylinder air charge, 6 events ahead", "H", 0.1, "mg",
                last(4, MG_PER_KG)),
            Did(0x0204, "manifold pressure std", "H", 0.001, "kPa", self._sigma(1)),
            Did(0x0205, "manifold temperature std", "H", 0.01, "K", self._sigma(2)),
            Did(0x0206, "cylinder air charge std", "H", 0.01, "mg", self._sigma(3, MG_PER_KG)),
            Did(0x0207, "cylinder air charge 6 events ahead std", "H", 0.01, "mg",
                self._sigma(4, MG_PER_KG)),
            validity_did(0x020F, "manifold estimate validity", lambda: self.validity),
        ]

    def _sigma(self, i: int, scale: float = 1.0) -> Reader:
        """Element i of the last event's sigmas (None before the first), scaled."""
        return lambda: None if self.sigmas is None else self.sigmas[i] * scale

    def variables(self) -> list[Variable]:
        """XCP measurements: the last event's estimates (SI), events filtered."""
        out = [Variable(f"manifold.{name}", unit, FLOAT, self._last(i), lo, hi, doc)
               for i, (name, unit, lo, hi, doc) in enumerate((
                   ("p_im_kpa", "kPa", 0, 200, "manifold pressure estimate"),
                   ("t_im_k", "K", 200, 400, "manifold temperature estimate"),
                   ("cac_kg", "kg", 0, 0.002, "cylinder air charge"),
                   ("cac_pred6_kg", "kg", 0, 0.002,
                    "cylinder air charge predicted 6 events ahead")), start=1)]
        out.append(Variable("manifold.events", "1", ULONG, lambda: self.events, 0, 4294967295,
                            "engine events filtered"))
        out.append(Variable("manifold.validity", "1", UBYTE, lambda: self.validity, 0, 3,
                            "0 init, 1 valid, 2 degraded, 3 invalid"))
        return out

