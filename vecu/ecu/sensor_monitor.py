"""Sensor diagnosis: timeout, range, E2E, stuck, plausibility against an estimator; DTCs.

One monitor per safety-relevant sensor (a function's monitors(): TPS, SWA, wheel speed). Each check is
debounced; the first to confirm sets the status (codes = THR_TpsStatus / STE_SwaStatus /
DIAG_*Status in the DBC) and the ECU substitutes the estimate. The status heals after `heal_ms` of
clean samples. The DTC follows its own lifecycle (Dtc): none -> pending (a check failing, not yet
debounced) -> confirmed (debounced) -> healed (`dtc_heal_ms` clean after the status healed) ->
confirmed again if the fault comes back. docs/scenarios.md describes it.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from vecu.clock import NS_PER_MS
from vecu.models.sensors import TpsCalibration

SOURCE_SENSOR, SOURCE_ESTIMATE = 0, 1  # THR_Source / STE_Source in the DBC


class SensorStatus(enum.IntEnum):
    OK = 0
    TIMEOUT = 1
    RANGE_LOW = 2
    RANGE_HIGH = 3
    E2E_ERROR = 4
    IMPLAUSIBLE = 5
    STUCK = 6


class DtcState(enum.IntEnum):
    """Values of ECU_TpsDtc / DIAG_*Dtc in the DBC."""

    NONE = 0
    PENDING = 1
    CONFIRMED = 2
    HEALED = 3


# the members as module constants for the per-tick code (an enum class attribute costs ~65 ns)
_OK, _TIMEOUT, _RANGE_LOW, _RANGE_HIGH, _E2E_ERROR, _IMPLAUSIBLE, _STUCK = SensorStatus
_NONE, _PENDING, _CONFIRMED, _HEALED = DtcState
# the states Dtc.report(t, failed=False, suspicious=False, ...) keeps as they are (none is never
# confirmed before, healed always: report's last branch)
_AT_REST = (_NONE, _HEALED)

SENDER_ALIVE_TICKS = 2  # ticks with the sender's traffic at a sensor's rate: it is running
# a sender reports its skipped ticks every 100 ms (PLANT_Host): a timeout is judged on the
# reports up to this long after it
SENDER_REPORT_WINDOW_NS = 250 * NS_PER_MS
TIMEOUT_EVENTS_KEPT = 64


@dataclass
class HostClock:
    """What the ECU node knows of its own running, shared with its sensor monitors (EcuNode
    keeps it): a gap the host caused must not read as a silent sensor.

    stalled_ns: total time the node was not running, i.e. base-tick releases it skipped (0 on
    the simulated clock). host_gap_ns: how long a silence may be excused as a stalled sender
    (0: never - simulated clock, replay; > 0 on a live bus, where saw() counts, per cycle time
    of the consumed periodic messages, the ticks that took a valid frame of one)."""

    stalled_ns: int = 0
    host_gap_ns: int = 0
    # what the sending node says its host did to it (PLANT_Host frames, live plant): ticks whose
    # frames it never sent, and sent late
    sender_skipped: int = 0
    sender_late: int = 0
    last_report_ns: int | None = None  # when the last PLANT_Host came
    # the sender's reports as they changed: (t_ns, skipped, late), the first one always
    reports: deque[tuple[int, int, int]] = field(default_factory=lambda: deque(maxlen=4096))
    _ticks: dict[int, int] = field(default_factory=dict)  # cycle -> ticks with such a frame
    _last: dict[int, int] = field(default_factory=dict)   # cycle -> the last of those ticks

    def saw(self, cycle_ns: int, t_ns: int) -> None:
        if self._last.get(cycle_ns) != t_ns:
            self._last[cycle_ns] = t_ns
            self._ticks[cycle_ns] = self._ticks.get(cycle_ns, 0) + 1

    def sender_report(self, t_ns: int, skipped: int, late: int) -> None:
        """A PLANT_Host frame: the sender's own count of skipped and late ticks so far."""
        if not self.reports or (skipped, late) != (self.sender_skipped, self.sender_late):
            self.reports.append((t_ns, skipped, late))
        self.sender_skipped, self.sender_late = skipped, late
        self.last_report_ns = t_ns

    def sender_counts_at(self, t_ns: int) -> tuple[int, int]:
        """The sender's (skipped, late) tick counts as last reported at or before t_ns (0, 0
        before any)."""
        counts = (0, 0)
        for t, skipped, late in self.reports:
            if t > t_ns:
                break
            counts = (skipped, late)
        return counts

    def activity(self, cycle_ns: int, before_ns: int | None = None) -> int:
        """Ticks so far (before before_ns, when given) that took a frame of a message sent at
        least as often as cycle_ns."""
        last = self._last
        return sum(n - (last[cycle] == before_ns) for cycle, n in self._ticks.items()
                   if cycle <= cycle_ns)


@dataclass(frozen=True)
class TimeoutEvent:
    """A sensor's frames went silent past the deadline (a new timeout): when, since when, and
    how long of that silence this ECU itself was not running."""

    t_ns: int
    last_rx_ns: int
    ecu_stalled_ns: int

    def cause(self, host: HostClock) -> dict:
        """Who dropped the frames, as far as the host can tell (issue 29): `sender-host` when
        the sender reported ticks it skipped or sent late (caught up) during the silence (PLANT_Host, judged on the reports
        up to SENDER_REPORT_WINDOW_NS after the timeout), `ecu-host` when this ECU was not running
        for part of it, else `sensor` (nothing on the host explains it)."""
        end = self.t_ns + SENDER_REPORT_WINDOW_NS
        skipped, late = (a - b for a, b in zip(host.sender_counts_at(end),
                                               host.sender_counts_at(self.last_rx_ns)))
        cause = ("sender-host" if skipped or late else "ecu-host" if self.ecu_stalled_ns > 0
                 else "sensor")
        return {"t_s": self.t_ns / 1e9, "silent_ms": (self.t_ns - self.last_rx_ns) / 1e6,
                "ecu_not_running_ms": self.ecu_stalled_ns / 1e6, "sender_skipped": skipped,
                "sender_late": late, "cause": cause}


class Dtc:
    """DTC lifecycle of one monitored item; report() once per evaluation.

    failed: a debounced fault is present; suspicious: a check fails but is not yet debounced;
    healthy: the item's status is ok again (healing clock runs only then). Transitions are kept in
    `history` as (t_ns, state); `on_change` (if set) is called on every transition.
    """

    def __init__(self, heal_ms: float) -> None:
        self.state = _NONE
        self.confirmations = 0
        self.history: list[tuple[int, DtcState]] = []
        self.on_change: Callable[[], None] | None = None
        self._heal_ns = int(heal_ms * NS_PER_MS)
        self._healthy_since: int | None = None
        self._was_confirmed = False

    def set_heal_ms(self, heal_ms: float) -> None:
        self._heal_ns = int(heal_ms * NS_PER_MS)

    def report(self, t_ns: int, failed: bool, suspicious: bool, healthy: bool) -> DtcState:
        state = self.state
        if failed:
            new = _CONFIRMED
            self._healthy_since = None
        elif state == _CONFIRMED:
            new = state
            if healthy:
                if self._healthy_since is None:
                    self._healthy_since = t_ns
                elif t_ns - self._healthy_since >= self._heal_ns:
                    new = _HEALED
            else:
                self._healthy_since = None
        elif suspicious:
            new = _PENDING
        else:
            new = _HEALED if self._was_confirmed else _NONE
        if new != state:
            if new == _CONFIRMED:
                self.confirmations += 1
                self._was_confirmed = True
            self.state = new
            self.history.append((t_ns, new))
            if self.on_change is not None:
                self.on_change()
        return new

    def clear(self, t_ns: int) -> None:
        """Forget the DTC (a tester's ClearDiagnosticInformation): state NONE, never confirmed;
        a fault still present confirms it again at the next evaluation."""
        self._healthy_since = None
        self._was_confirmed = False
        if self.state != _NONE:
            self.state = _NONE
            self.history.append((t_ns, _NONE))
            if self.on_change is not None:
                self.on_change()


COUNT = {"bounds": (1, 1_000_000_000)}


@dataclass(frozen=True)
class SensorMonitorConfig:
    # from the DBC (GenMsgCycleTime of the sensor's frame): set by the function, not a parameter
    cycle_ms: float = field(default=1.0, metadata={"param": False})
    # bounds: what a monitor can honour (a debounce of 0 would confirm on nothing at all)
    timeout_cycles: int = field(default=3, metadata=COUNT)  # frames stop: 3 missed periods
    range_debounce: int = field(default=2, metadata=COUNT)  # consecutive out-of-range samples
    e2e_debounce: int = field(default=2, metadata=COUNT)    # consecutive CRC/counter errors
    # identical raw readings in a row (needs sensor noise; 0: no stuck check)
    stuck_samples: int = field(default=8, metadata={"bounds": (0, 1_000_000)})
    plaus_sigma: float = field(default=5.0, metadata={"bounds": (0.0, 1e3)})  # gate in sigmas ...
    # ... plus a fixed margin (physical units, deg here)
    plaus_margin: float = field(default=4.0, metadata={"bounds": (0.0, 1e6)})
    plaus_debounce: int = field(default=5, metadata=COUNT)  # up/down counter threshold
    heal_ms: float = 500.0         # clean time before the sensor is trusted again
    dtc_heal_ms: float = 5000.0    # healthy time after that before the DTC reads 'healed'
    enabled: bool = True           # False: no checks at all (a broken ECU, for scenario tests)


class SensorMonitor:
    """Feed on_frame()/on_e2e_error() as frames arrive, then evaluate() once per function run.

    raw_low/raw_high bound the valid raw signal (range checks run on the raw value, e.g. volts);
    to_physical maps a raw value to the quantity compared with the estimator (deg).

    Receive deadline: the silence since the last frame is charged to the sensor less the time
    the ECU was not running (`host`, set by EcuNode); a silence of the sender's traffic at the
    sensor's rate (the sender stalled) is excused up to host.host_gap_ns (live). An excused gap is a `host_gap`: status stays ok, the
    estimate is broadcast (the last sample is stale), and `host_gaps` counts them.
    """

    def __init__(self, config: SensorMonitorConfig, raw_low: float, raw_high: float,
                 to_physical: Callable[[float], float]) -> None:
        self.cfg = config
        self._low, self._high = raw_low, raw_high
        self._to_physical = to_physical
        self.status = _OK
        self.timeouts = 0  # confirmed timeouts (select())
        self.dtc_item = Dtc(config.dtc_heal_ms)
        self.status_history: list[tuple[int, SensorStatus]] = []  # (t_ns, status) transitions
        self.first_fault_ns: int | None = None
        self.first_fault_status: SensorStatus | None = None
        self.value: float | None = None     # last valid sensor value (physical)
        self._raw: float | None = None
        self._fresh = False
        self._last_rx_ns: int | None = None
        self._range_low = self._range_high = 0
        self._e2e_bad = 0
        self._same = 0
        self._plaus = 0
        self._clean_since_ns: int | None = None
        self._timeout_ns = int(config.timeout_cycles * config.cycle_ms * NS_PER_MS)
        self._cycle_ns = int(config.cycle_ms * NS_PER_MS)
        self.host = HostClock()   # replaced by the node's own (EcuNode)
        self._stalled_at_rx = 0
        self._activity_at_rx = 0
        self.host_gap = False     # the current sample is stale, but not for the sensor's fault
        self.host_gaps = 0        # host gaps seen (each counted once)
        # the last new timeouts with the host's part in them (timeout_causes())
        self.timeout_events: deque[TimeoutEvent] = deque(maxlen=TIMEOUT_EVENTS_KEPT)

    def recalibrate(self, config: SensorMonitorConfig) -> None:
        """A new calibration (XCP, a timed set): acts from the next evaluation; the state
        (counters, status, DTC) stays. Equal to a monitor built with it (cycle_ms is the
        frame's, kept)."""
        config = replace(config, cycle_ms=self.cfg.cycle_ms)
        self.cfg = config
        self._timeout_ns = int(config.timeout_cycles * config.cycle_ms * NS_PER_MS)
        self.dtc_item.set_heal_ms(config.dtc_heal_ms)

    @classmethod
    def for_tps(cls, config: SensorMonitorConfig, cal: TpsCalibration) -> SensorMonitor:
        """Range checks on the voltage (open / short circuit), plausibility on the angle."""
        return cls(config, cal.fault_low_v, cal.fault_high_v, cal.angle)

    def on_frame(self, t_ns: int, raw: float) -> None:
        """A frame that passed DLC/E2E/value checks."""
        self._same = self._same + 1 if raw == self._raw else 0
        self._raw = raw
        self._last_rx_ns = t_ns
        self._e2e_bad = 0
        self._fresh = True
        self._range_low = self._range_low + 1 if raw < self._low else 0
        self._range_high = self._range_high + 1 if raw > self._high else 0
        self.value = self._to_physical(raw)
        host = self.host
        self._stalled_at_rx = host.stalled_ns
        if host.host_gap_ns:
            self._activity_at_rx = host.activity(self._cycle_ns)

    def on_e2e_error(self) -> None:
        self._e2e_bad += 1

    def evaluate(self, t_ns: int, est: float, est_std: float) -> SensorStatus:
        cfg = self.cfg
        finding = _OK
        last_rx = 0 if self._last_rx_ns is None else self._last_rx_ns  # run start counts as rx
        gap = False
        if not cfg.enabled:
            pass
        elif t_ns - last_rx >= self._timeout_ns and not (gap := self._host_gap(t_ns, last_rx)):
            finding = _TIMEOUT
        else:
            if self._e2e_bad >= cfg.e2e_debounce:
                finding = _E2E_ERROR
            elif self._range_low >= cfg.range_debounce:
                finding = _RANGE_LOW
            elif self._range_high >= cfg.range_debounce:
                finding = _RANGE_HIGH
            elif cfg.stuck_samples and self._same + 1 >= cfg.stuck_samples:
                finding = _STUCK
            elif self._fresh and self.value is not None:
                gate = cfg.plaus_sigma * est_std + cfg.plaus_margin
                if abs(self.value - est) > gate:
                    if self._plaus < cfg.plaus_debounce:  # saturating up/down counter
                        self._plaus += 1
                elif self._plaus > 0:
                    self._plaus -= 1
                if self._plaus >= cfg.plaus_debounce:
                    finding = _IMPLAUSIBLE
        self._fresh = False
        if finding == _TIMEOUT and self.status == _OK:
            self.timeout_events.append(TimeoutEvent(
                t_ns, last_rx, self.host.stalled_ns - self._stalled_at_rx))
        if gap and not self.host_gap:
            self.host_gaps += 1
        self.host_gap = gap
        return self._update(t_ns, finding)

    def _host_gap(self, t_ns: int, last_rx: int) -> bool:
        """A silence past the deadline that the host caused: less than a timeout of it while
        the ECU ran, or (live, shorter than host_gap_ns) the sender's traffic at this sensor's
        rate has stopped too: fewer than SENDER_ALIVE_TICKS ticks since the sensor's last frame
        took a frame of a message sent at least as often. Not counted: the current tick (a
        sender back from a stall may send its other frames first); tolerated: one such tick
        before (a sender stalled mid-tick finishes that tick's frames late). A sensor whose
        companion frames go on is silent."""
        host = self.host
        charged = t_ns - last_rx - (host.stalled_ns - self._stalled_at_rx)
        if charged < self._timeout_ns:
            return True
        if charged >= host.host_gap_ns:
            return False
        return host.activity(self._cycle_ns, t_ns) - self._activity_at_rx < SENDER_ALIVE_TICKS

    def _update(self, t_ns: int, finding: SensorStatus) -> SensorStatus:
        status = self.status
        if finding != _OK:
            if status == _OK:
                status = self.status = finding
                self.status_history.append((t_ns, finding))
                if self.first_fault_ns is None:
                    self.first_fault_ns = t_ns
                    self.first_fault_status = finding
            self._clean_since_ns = None
        elif status != _OK:
            if self._clean_since_ns is None:
                self._clean_since_ns = t_ns
            elif t_ns - self._clean_since_ns >= self.cfg.heal_ms * NS_PER_MS:
                status = self.status = _OK
                self.status_history.append((t_ns, status))
                self._plaus = 0
        suspicious = (self._plaus or self._e2e_bad or self._range_low or self._range_high
                      or (self.cfg.stuck_samples and self._same >= self.cfg.stuck_samples // 2))
        dtc = self.dtc_item
        # a clean evaluation leaves a DTC at rest (none, or healed) as it is: no report call
        if finding != _OK or suspicious or dtc.state not in _AT_REST:
            dtc.report(t_ns, finding != _OK, bool(suspicious), status == _OK)
        return status

    @property
    def raw(self) -> float | None:
        """The last valid raw reading (e.g. the TPS voltage), None before the first frame."""
        return self._raw

    @property
    def last_rx_ns(self) -> int | None:
        """When the last valid frame came (None: none yet)."""
        return self._last_rx_ns

    @property
    def dtc(self) -> DtcState:
        return self.dtc_item.state

    def report(self) -> dict:
        """Diagnosis record for the run summary (times in s)."""
        dtc = self.dtc_item
        return {"status": self.status.name.lower(), "dtc": dtc.state.name.lower(),
                "confirmations": dtc.confirmations, "timeouts": self.timeouts,
                "host_gaps": self.host_gaps,
                "first_fault_s": None if self.first_fault_ns is None else self.first_fault_ns / 1e9,
                "first_fault_status": (self.first_fault_status.name.lower()
                                       if self.first_fault_status else None),
                "status_history": [(t / 1e9, st.name.lower()) for t, st in self.status_history],
                "dtc_history": [(t / 1e9, st.name.lower()) for t, st in dtc.history]}

    def timeout_causes(self) -> list[dict]:
        """The kept timeouts (the last TIMEOUT_EVENTS_KEPT), each with its cause as far as the
        host can tell (TimeoutEvent.cause)."""
        return [event.cause(self.host) for event in self.timeout_events]

    def select(self, t_ns: int, est: float, est_std: float) -> tuple[float, int, SensorStatus]:
        """Diagnose (evaluate) and pick what to broadcast: (value, source, status), the sensor's
        last valid value while it is healthy (SOURCE_SENSOR), else the estimate (SOURCE_ESTIMATE).
        A newly confirmed timeout is counted in `timeouts`."""
        was_ok = self.status == _OK
        status = self.evaluate(t_ns, est, est_std)
        if was_ok and status == _TIMEOUT:
            self.timeouts += 1
        if status == _OK and self.value is not None and not self.host_gap:
            return self.value, SOURCE_SENSOR, status
        return est, SOURCE_ESTIMATE, status

    @property
    def healthy(self) -> bool:
        return self.status == _OK

