"""Virtual ECU node: receive and validate frames, run its functions, broadcast status.

One 1 ms base task, like an ECU's OS: read the receive queue, at most RxBudget frames per tick
(a flood is shed and counted, never stalls the tick; each frame is checked for kind,
known ID, DLC, E2E CRC and alive counter, NaN / out-of-range values, and counted when rejected),
hand validated values to the function that subscribed to the message, run every function whose
period divides the current time (throttle 1 ms, speed 2 ms), and send ECU_Status at its DBC cycle
time. Nothing a frame contains can raise out of tick(), nor anything a client makes a diagnostic
server (UDS, XCP) do: such an error stops at BusNode.handler_failed, counted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Protocol

import can

from vecu.bus import BusNode, RxBudget
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec, FrameCodec
from vecu.e2e import AliveCounterCheck
from vecu.ecu.sensor_monitor import Dtc, HostClock, SensorMonitor

log = logging.getLogger(__name__)

MAX_LOGGED_PER_KIND = 20  # rx problems logged individually before going quiet (still counted)
Send = Callable[[can.Message], bool]
Checked = tuple[bool, dict[str, float], list[str]]  # a frame's CRC ok, values, bad signals
BUS_ERROR_LIMIT = 10  # error frames per ECU_Status period (100 ms) that confirm the bus DTC
BUS_DTC_HEAL_MS = 5000.0


@dataclass
class RxCounters:
    """Receive statistics; every frame lands in exactly one of accepted / ignored / a reject bin."""

    received: int = 0
    accepted: int = 0
    ignored: int = 0           # known IDs this ECU does not consume (incl. own echoed frames)
    unknown_id: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    dlc_errors: int = 0
    crc_errors: int = 0
    counter_errors: int = 0
    value_errors: int = 0      # NaN / inf / outside the DBC range / refused as implausible
    implausible: int = 0       # of value_errors: in range, refused by the function (not a bin)
    malformed: int = 0         # anything else the decoder refused
    diagnostic: int = 0        # frames on the diagnostic server's IDs (UDS requests, echoes)
    shed: int = 0              # read past the tick's RxBudget and dropped undecoded (a flood)

    @property
    def rejected(self) -> int:
        return (self.unknown_id + self.error_frames + self.remote_frames + self.dlc_errors
                + self.crc_errors + self.counter_errors + self.value_errors + self.malformed)

    def as_dict(self) -> dict[str, int]:
        return {**asdict(self), "rejected": self.rejected}


@dataclass(frozen=True)
class Subscription:
    """A message a function consumes: validated values go to on_values(values, t_ns), which
    may refuse implausible ones by returning the reason (a value error; None: taken);
    E2E failures (CRC or alive counter) to on_e2e_error(), when given."""

    message: str
    on_values: Callable[[dict[str, float], int], str | None]
    on_e2e_error: Callable[[], None] | None = None


class EcuFunction(Protocol):
    """One job of the ECU (throttle, speed, ...), run every period_ns from the base tick."""

    name: str
    period_ns: int
    timeouts: int

    def subscriptions(self) -> list[Subscription]: ...

    def run(self, t_ns: int, send: Send) -> None: ...

    def status_signals(self) -> dict[str, int]: ...


class DiagnosticServer(Protocol):
    """A diagnostic server on the node (vecu.uds, vecu.xcp): it claims CAN IDs (frames on them
    go to on_frame() instead of the functions) and works in bounded steps from tick(), called
    after the functions have sent this tick's broadcast."""

    ids: frozenset[tuple[int, bool]]

    def on_frame(self, msg: can.Message, t_ns: int) -> None: ...

    def tick(self, t_ns: int) -> None: ...


@dataclass(frozen=True)
class Route:
    """How one received CAN ID reaches the functions: its codec, the subscription, the alive
    counter check (E2E messages) and the functions it feeds (armed by its first frame)."""

    codec: FrameCodec
    subscription: Subscription
    counter: AliveCounterCheck | None
    feeds: tuple[EcuFunction, ...]
    cycle_ns: int = 0  # the message's cycle time (0: event-driven or unknown)


def native_routes(codec: DbcCodec, functions: list[EcuFunction]) -> dict[tuple[int, bool], Route]:
    """Each function consumes its subscribed messages of vecu's own DBC."""
    routes = {}
    for fn in functions:
        for sub in fn.subscriptions():
            fc = codec[sub.message]
            counter = (AliveCounterCheck(fc.e2e.protection.counter_modulo)
                       if fc.e2e is not None else None)
            routes[(fc.frame_id, fc.is_extended)] = Route(
                fc, sub, counter, (fn,), round((fc.cycle_time_ms or 0) * NS_PER_MS))
    return routes


# receive()'s view of a route: (route, payload length, crc_ok (None: no E2E), decode_checked
# (decode_exact and bad_values), alive counter check (None: none), its signal, subscription,
# its on_values)
_Plan = tuple[Route, int, Callable[[bytes | bytearray], bool] | None,
              Callable[[bytes | bytearray], tuple[dict[str, float], list[str]]],
              AliveCounterCheck | None, str, Subscription,
              Callable[[dict[str, float], int], str | None]]


def _plan(route: Route) -> _Plan:
    fc = route.codec
    e2e = fc.e2e
    return (route, fc.length, fc.crc_ok if e2e is not None else None, fc.decode_checked,
            route.counter, e2e.counter_signal if e2e is not None else "",
            route.subscription, route.subscription.on_values)


def _muted(msg: can.Message) -> bool:
    """The send of a node whose broadcast a tester stopped: nothing goes out."""
    return False


class EcuNode(BusNode):
    """The virtual ECU; call tick(t_ns) from a 1 ms scheduler task."""

    def __init__(self, bus: can.BusABC, codec: DbcCodec, functions: list[EcuFunction], *,
                 routes: dict[tuple[int, bool], Route] | None = None,
                 rx_codec: DbcCodec | None = None, arm_on_input: bool = False,
                 tick_ns: int = NS_PER_MS, host_gap_ms: float = 0.0,
                 tap: Callable[[can.Message], None] | None = None,
                 rx_budget: RxBudget = RxBudget(), log_rx_problems: bool = True,
                 tallied_rx: frozenset[str] = frozenset()) -> None:
        """codec encodes the ECU's own frames. By default the functions consume their messages
        of that codec; `routes` (trace replay with a signal map) replaces that table, and
        `rx_codec` is the database that tells an ignored (known) ID from an unknown one.

        Functions run from boot (a missing sensor is then a timeout); with arm_on_input (trace
        replay) each one starts at its first accepted input, so a trace without a function's
        inputs gives no estimates from nothing.

        tick_ns: the base tick's period; a later tick means the node was not running (its
        releases were skipped), which the sensor monitors do not charge to a sensor.
        host_gap_ms (live bus): a sensor silence shorter than this while the sender's traffic
        at the sensor's rate stopped too is a stalled sender, not a silent sensor (HostClock;
        0 on the simulated clock).
        tap (trace replay): sees every frame the node sends.
        rx_budget: frames taken in per tick, then shed (`ecu.rx.*`; frames handed to receive()
        directly, as a trace replay does, are never shed).
        log_rx_problems=False (a replay's kernel warm-up): frames it cannot take are counted,
        never logged; tallied_rx: kinds of receive problem counted, not logged one by one (the
        caller reports them in one line: a replay's tally of IDs not in the database)."""
        super().__init__(bus, "ecu", tap, rx_budget)
        self._log_rx_problems = log_rx_problems
        self._tallied_rx = tallied_rx
        self.codec = codec
        self.rx_codec = rx_codec if rx_codec is not None else codec
        self.functions = functions
        self.rx = RxCounters()
        self.overruns = 0  # set by the runner from the scheduler's count
        self._consumers = routes if routes is not None else native_routes(codec, functions)
        # per consumed key what receive() uses of its route, looked up once (_Plan)
        self._plans: dict[tuple[int, bool], _Plan] = {
            key: _plan(route) for key, route in self._consumers.items()}
        # arm_on_input: a function runs from its first input frame; one that reads no frame
        # (an FMU without inputs) runs on the clock from the start
        fed = {id(f) for r in self._consumers.values() for f in r.feeds}
        self._armed: list[EcuFunction] = [f for f in functions
                                          if not arm_on_input or id(f) not in fed]
        # routes whose first accepted frame has not come yet (arm_on_input only)
        self._unarmed: set[int] = {id(r) for r in self._consumers.values()} if arm_on_input else set()
        self._status = codec["ECU_Status"]
        self._status_period_ns = int((self._status.cycle_time_ms or 100) * NS_PER_MS)
        self._next_status_ns = 0
        self._status_counter = 0
        # diagnostics (ECU_Diag): the functions' sensor monitors and the bus-error DTC
        self.monitors: dict[str, SensorMonitor] = {}
        for fn in functions:
            self.monitors.update(getattr(fn, "monitors", dict)())
        self.bus_dtc = Dtc(heal_ms=BUS_DTC_HEAL_MS)
        self._diag = codec["ECU_Diag"] if "ECU_Diag" in codec else None  # noqa: SIM401 (no .get)
        self._diag_dirty = False
        self._diag_counter = 0
        # a live plant's report of its own delays (PLANT_Host): kept in self.host
        sender = self.rx_codec["PLANT_Host"] if "PLANT_Host" in self.rx_codec else None  # noqa: SIM401 (DbcCodec has no .get)
        self._sender_report = (None if sender is None
                               else ((sender.frame_id, sender.is_extended), sender))
        self._errors_seen = 0
        for dtc in [m.dtc_item for m in self.monitors.values()] + [self.bus_dtc]:
            dtc.on_change = self._mark_diag
        self.host = HostClock(host_gap_ns=round(host_gap_ms * NS_PER_MS))
        for mon in self.monitors.values():
            mon.host = self.host
        self._tick_ns = tick_ns
        self._track_senders = host_gap_ms > 0
        self._last_tick_ns: int | None = None
        self._logged: dict[str, int] = {}
        # diagnostics (vecu.uds): a server on its own IDs, the broadcast switch (0x28) and the
        # sensor values a tester overrides (0x2F), by message: {signal: value}
        self.diagnostics: DiagnosticServer | None = None  # the first attached (UDS)
        self.servers: list[DiagnosticServer] = []         # all, ticked in attach order
        self._server_of: dict[tuple[int, bool], DiagnosticServer] = {}
        self._diag_ids: frozenset[tuple[int, bool]] = frozenset()
        self._app_send: Send = self.send
        self.broadcast_enabled = True
        self.overrides: dict[str, dict[str, float]] = {}
        # the sensor's own values of the last frame of each overridden message (what the ECU
        # would see without the override: returnControlToECU answers with it)
        self.own_values: dict[str, dict[str, float]] = {}

    def attach(self, server: DiagnosticServer) -> None:
        """Serve diagnostics: frames on server.ids go to it, and it ticks after the functions
        (servers in attach order; their IDs must not overlap)."""
        clash = self._diag_ids & server.ids
        if clash:
            raise ValueError(f"CAN IDs {sorted(hex(i) for i, _ in clash)} already claimed")
        if self.diagnostics is None:
            self.diagnostics = server
        self.servers.append(server)
        for key in server.ids:
            self._server_of[key] = server
        self._diag_ids = frozenset(self._server_of)

    def set_broadcast(self, enabled: bool) -> None:
        """CommunicationControl: the functions and ECU_Status / ECU_Diag stop or resume sending
        (they still run; a muted frame counts as not sent)."""
        self.broadcast_enabled = enabled
        self._app_send = self.send if enabled else _muted

    def set_override(self, message: str, signal: str, value: float | None) -> None:
        """InputOutputControl: the value the functions see for message.signal (None: the
        sensor's own again). Applied to each frame that passed the receive checks."""
        if message not in self.overrides:
            self.own_values.pop(message, None)  # none yet of this override
        over = self.overrides.setdefault(message, {})
        if value is None:
            over.pop(signal, None)
            if not over:
                del self.overrides[message]
        else:
            over[signal] = value

    def own_value(self, message: str, signal: str) -> float | None:
        """The sensor's own value of message.signal in the last frame that came while it was
        overridden (None: none came)."""
        return self.own_values.get(message, {}).get(signal)

    @property
    def consumed_ids(self) -> frozenset[tuple[int, bool]]:
        """The (CAN ID, extended) keys the ECU takes: its functions' inputs and, with a
        diagnostic server attached, the server's request IDs."""
        return frozenset(self._consumers) | self._diag_ids

    @property
    def armed(self) -> list[EcuFunction]:
        """Functions that run (all, unless arm_on_input and no input has arrived yet)."""
        return list(self._armed)

    def _arm(self, route: Route) -> None:
        self._unarmed.discard(id(route))
        self._armed = [f for f in self.functions if f in self._armed or f in route.feeds]

    def function(self, name: str) -> EcuFunction | None:
        return next((f for f in self.functions if f.name == name), None)

    # ---------------------------------------------------------------- receive
    def _problem(self, kind: str, msg: can.Message, detail: str = "") -> None:
        n = self._logged.get(kind, 0) + 1
        self._logged[kind] = n
        if n <= MAX_LOGGED_PER_KIND and self._log_rx_problems and kind not in self._tallied_rx:
            log.warning("ecu rx %s: id=0x%X dlc=%d data=%s %s%s", kind, msg.arbitration_id,
                        msg.dlc, bytes(msg.data).hex(), detail,
                        " (further ones counted, not logged)" if n == MAX_LOGGED_PER_KIND else "")

    def receive(self, msg: can.Message, t_ns: int, checked: Checked | None = None) -> None:
        """Validate one frame and hand its values to the subscribed function. A frame the ECU
        cannot take is counted and logged, never raised; an exception out of the function it
        feeds is a bug, not the frame's fault: it propagates (like one out of the function's
        run()), so that it is a traceback, not a count of malformed frames. `checked`: the
        frame's (CRC ok, values, bad signals) from its route codec's check_block (a replay
        decodes the trace in blocks), instead of checking it here; the same checks follow."""
        rx = self.rx
        rx.received += 1
        try:
            if msg.is_error_frame:
                rx.error_frames += 1
                self._problem("error-frame", msg)
                return
            if msg.is_remote_frame:  # no payload to use, whatever its ID
                rx.remote_frames += 1
                self._problem("remote-frame", msg)
                return
            key = (msg.arbitration_id, msg.is_extended_id)
            plan = self._plans.get(key)
            if plan is None:
                server = self._server_of.get(key)
                if server is not None:
                    rx.diagnostic += 1
                    try:
                        server.on_frame(msg, t_ns)
                    except Exception as exc:  # noqa: BLE001 - the handler boundary: counted
                        self.handler_failed(f"{type(server).__name__}.on_frame", exc)
                    return
                if key in self.rx_codec.by_id:
                    rx.ignored += 1
                    report = self._sender_report
                    if report is not None and key == report[0] and len(msg.data) == report[1].length:
                        values = report[1].decode(msg.data)
                        self.host.sender_report(t_ns, int(values["PH_SkippedSends"]),
                                                int(values["PH_LateSends"]))
                else:
                    rx.unknown_id += 1
                    self._problem("unknown-id", msg)
                return
            # the checks of one frame, in order (inline: this runs for every frame received)
            route, length, crc_ok, decode_checked, counter, counter_signal, sub, on_values = plan
            data = msg.data
            if len(data) != length:
                rx.dlc_errors += 1
                self._problem("dlc", msg, f"expected {length} bytes")
                return
            if crc_ok is not None and not (checked[0] if checked is not None else crc_ok(data)):
                rx.crc_errors += 1
                self._e2e_failure("crc", msg, sub)
                return
            # decode and range check (bad: the signals NaN / inf or outside the DBC range)
            values, bad = (checked[1], checked[2]) if checked is not None else decode_checked(data)
            # the counter belongs to E2E: checked on every CRC-valid frame, whatever its values
            if counter is not None and not counter.check(int(values[counter_signal])):
                rx.counter_errors += 1
                self._e2e_failure("alive-counter", msg, sub)
                return
            if bad:
                rx.value_errors += 1
                self._problem("value", msg, f"bad {', '.join(bad)}")
                return
        except Exception as exc:  # noqa: BLE001 - a frame the decoder cannot take: counted
            rx.malformed += 1
            self._problem("malformed", msg, f"{type(exc).__name__}: {exc}")
            return
        # deliver the values to the function
        if self._track_senders and route.cycle_ns:  # live: the sender is running (HostClock)
            self.host.saw(route.cycle_ns, t_ns)
        if self.overrides and sub.message in self.overrides:
            self.own_values[sub.message] = values
            values = {**values, **self.overrides[sub.message]}
        if on_values(values, t_ns):  # the function refused them (it logs them)
            rx.value_errors += 1
            rx.implausible += 1
            return
        rx.accepted += 1
        if self._unarmed and id(route) in self._unarmed:
            self._arm(route)

    def _e2e_failure(self, kind: str, msg: can.Message, sub: Subscription) -> None:
        self._problem(kind, msg)
        if sub.on_e2e_error:
            sub.on_e2e_error()

    # ------------------------------------------------------------------- tick
    def tick(self, t_ns: int) -> None:
        host = self.host
        last = self._last_tick_ns
        if last is not None and t_ns - last > self._tick_ns:  # releases skipped: not running
            host.stalled_ns += t_ns - last - self._tick_ns
        self._last_tick_ns = t_ns
        recv = self.bus.recv
        n = self.rx_budget.frames_per_tick
        while (msg := recv(0.0)) is not None:
            self.receive(msg, t_ns)
            n -= 1
            if not n:
                self._shed(t_ns)
                break
        else:  # the bus emptied: no backlog
            self.rx_saturated = 0
            self.rx_peak = max(self.rx_peak, self.rx_budget.frames_per_tick - n)
        send = self._app_send
        for fn in self._armed:
            if t_ns % fn.period_ns == 0:
                fn.run(t_ns, send)
        if t_ns >= self._next_status_ns:
            self._next_status_ns += self._status_period_ns
            self._send_status(t_ns / NS_PER_S)
            self._bus_diagnosis(t_ns)
            self._send_diag(t_ns, on_change=False)
        elif self._diag_dirty:
            self._send_diag(t_ns, on_change=True)
        for server in self.servers:
            try:
                server.tick(t_ns)
            except Exception as exc:  # noqa: BLE001 - the handler boundary: counted
                self.handler_failed(f"{type(server).__name__}.tick", exc)

    def _shed(self, t_ns: int) -> None:
        """The tick's frames past its budget: shed, except diagnostic requests (their server
        queues them, bounded), so that a tester is still heard during a flood."""
        server_of, before = self._server_of, self.rx_shed

        def keep(msg: can.Message) -> bool:
            if (msg.arbitration_id, msg.is_extended_id) not in server_of:
                return False
            self.receive(msg, t_ns)
            return True

        self.shed(keep)
        rx = self.rx
        rx.received += self.rx_shed - before
        rx.shed = self.rx_shed

    def _mark_diag(self) -> None:
        self._diag_dirty = True

    def _bus_diagnosis(self, t_ns: int) -> None:
        """Error frames per status period: pending on any, confirmed at BUS_ERROR_LIMIT."""
        errors = self.rx.error_frames - self._errors_seen
        self._errors_seen = self.rx.error_frames
        self.bus_dtc.report(t_ns, errors >= BUS_ERROR_LIMIT, errors > 0, errors == 0)

    def _send_diag(self, t_ns: int, on_change: bool) -> None:
        """ECU_Diag: DTC state and status per monitored sensor (0 when not configured)."""
        self._diag_dirty = False
        if self._diag is None:
            return
        signals = {"DIAG_Counter": self._diag_counter, "DIAG_BusDtc": int(self.bus_dtc.state),
                   "DIAG_ErrorFrames": min(self.rx.error_frames, 255),
                   "DIAG_RemoteFrames": min(self.rx.remote_frames, 255),
                   "DIAG_RxShed": min(self.rx.shed, 127),
                   "DIAG_OnChange": int(on_change)}
        confirmations = self.bus_dtc.confirmations
        for name, prefix in (("tps", "Tps"), ("swa", "Swa"), ("wheel", "Wheel")):
            mon = self.monitors.get(name)
            signals[f"DIAG_{prefix}Dtc"] = int(mon.dtc) if mon else 0
            signals[f"DIAG_{prefix}Status"] = int(mon.status) if mon else 0
            confirmations += mon.dtc_item.confirmations if mon else 0
        signals["DIAG_Confirmations"] = min(confirmations, 255)
        self._app_send(self._diag.frame(signals, t_ns / NS_PER_S))
        self._diag_counter = (self._diag_counter + 1) & 0xF

    def _send_status(self, ts: float) -> None:
        rx = self.rx
        signals = {"ECU_TpsDtc": 0}
        for fn in self.functions:
            signals.update(fn.status_signals())
        timeouts = sum(fn.timeouts for fn in self.functions)
        self._app_send(self._status.frame({
            **signals,
            "ECU_StatusCounter": self._status_counter,
            "ECU_Overruns": min(self.overruns, 65535),
            "ECU_RxDlcErrors": min(rx.dlc_errors, 255),
            "ECU_RxE2EErrors": min(rx.crc_errors + rx.counter_errors, 255),
            "ECU_RxValueErrors": min(rx.value_errors + rx.malformed, 255),
            "ECU_RxUnknownIds": min(rx.unknown_id, 255),
            "ECU_RxTimeouts": min(timeouts, 255),
        }, ts))
        self._status_counter = (self._status_counter + 1) & 0xF
