"""ECU manifold function: intake manifold state and cylinder air charge per engine event
(Dutka 2006).

Each engine event brings ENG_Event and ENG_Intake (same counter). On the next 1 ms base tick
the function runs its filter (the live SDKF: one warm-started Riccati iteration per event, or
the EKF) once per complete event, predicts the cylinder air charge 6 events ahead with the
setpoint held (the ECU does not know future pedal positions), and sends ECU_ManifoldEstimate.
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
from vecu.ecu.node import Send, Subscription
from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac
from vecu.estimators.manifold.factory import make_filter
from vecu.estimators.manifold.filters import ManifoldFilterConfig, input_problem
from vecu.models.manifold import cylinder_air_charge, nominal_input
from vecu.models.manifold_params import EngineInput
from vecu.units import KELVIN_AT_0_DEGC, MG_PER_KG, RAD_PER_DEG

log = logging.getLogger(__name__)


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
        """stopwatch times the filter and the prediction (filter_seconds, predict_seconds)."""
        self.filter = make_filter(config.filter, config.kf)
        self.filter_name = config.filter
        self._engine = self.filter.params  # the calibration: filter, CAC and prediction
        self._kf = config.kf
        self._out = codec["ECU_ManifoldEstimate"]
        # the adaptive filter's corrections (ECU_ManifoldAdapt), sent only with that filter
        self._adapt_out = codec["ECU_ManifoldAdapt"] if config.filter == "adaptive" else None
        self.timeouts = 0
        self.estimates_sent = 0
        self.events = 0          # complete events filtered
        self.lost_events = 0     # counter gaps (frames lost or rejected)
        self.implausible_inputs = 0  # ENG_Event frames refused (engine speed outside n_range...)
        self.estimator_faults = 0    # non-finite CAC outputs caught here (should stay 0)
        self._refused_in_row = 0
        self.filter_seconds = 0.0   # time in the filter step (us/event in the summary)
        self.predict_seconds = 0.0  # time in the 6-event CAC prediction
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
            if self._refused_in_row == 1:
                log.warning("ecu manifold: engine event %d refused: %s (further ones counted, "
                            "logged again after a plausible event)",
                            int(values["ENG_EventCounter"]), problem)
            return problem
        if self._refused_in_row:
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
        t_meas = iat[1] if iat is not None and iat[0] == counter else None
        n_rpm = u.n_rpm
        y = (ev["ENG_ThrottleAngle"] * RAD_PER_DEG, ev["ENG_MAP"],
             t_meas if t_meas is not None else math.nan)  # NaN channel: rejected, others used
        watch = self._watch
        watch.lap()
        x = self.filter.step(y, u)
        filter_s = watch.lap()
        # the adaptive filter's eta correction as the CAC uses it (ManifoldAdaptive.eta_used)
        scale = (float(self.filter.eta_used(float(x[6]), float(self.filter.P_post[6, 6])))
                 if len(x) > 6 else 1.0)
        cac = scale * cylinder_air_charge(float(x[3]), float(x[4]), n_rpm, self._engine)
        first = self.filter.last_prediction  # the filter already ran event n+1 from x
        if first is not None and first[0] is u:
            cac6 = predict_cac(first[1], [u] * (HORIZON - 1), self._engine, scale)
        else:
            cac6 = predict_cac(x, [u] * HORIZON, self._engine, scale)
        self.filter_seconds += filter_s
        self.predict_seconds += watch.lap()
        if not (math.isfinite(cac) and math.isfinite(cac6)):  # last line of defence
            self.estimator_faults += 1
            self.filter.reset()
            return
        self.events += 1
        self.last = (self._abs_index, float(x[3]), float(x[4]), cac, cac6)
        self.estimates_sent += send(self._out.frame({
            "MFD_ThrottleAngle": float(x[1]) / RAD_PER_DEG, "MFD_Pressure": float(x[3]),
            "MFD_Temperature": float(x[4]) - KELVIN_AT_0_DEGC, "MFD_CAC": cac * MG_PER_KG,
            "MFD_CACPred6": cac6 * MG_PER_KG}, t_ns / NS_PER_S))
        if self._adapt_out is not None:
            sigma = math.sqrt(max(float(self.filter.P_post[6, 6]), 0.0))
            self.estimates_sent += send(self._adapt_out.frame({
                "MFD_EtaCorr": 100.0 * (scale - 1.0), "MFD_EtaCorrStd": 100.0 * sigma,
                "MFD_FlowCorr": 100.0 * (float(x[7]) - 1.0),
                "MFD_TaGainCorr": 100.0 * (float(x[8]) - 1.0),
                "MFD_ActZetaCorr": 100.0 * (float(x[9]) - 1.0),
                "MFD_ActOmegaCorr": 100.0 * (float(x[10]) - 1.0)}, t_ns / NS_PER_S))

    def status_signals(self) -> dict[str, int]:
        return {}

