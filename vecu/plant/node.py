"""Plant node: the simulated vehicle on the bus, one part per physical system (vecu.plant.part),
each stepped at its own rate and sending its sensor frames; the node owns the bus and obeys
FI_Command frames for the fault injector (docs/architecture.md).
"""

from __future__ import annotations

import logging

import can

from vecu.bus import BusNode
from vecu.clock import NS_PER_S
from vecu.codec import DbcCodec
from vecu.faults import FaultInjector, fault_event_signals
from vecu.models.manifold import (
    nominal_input,
    steady_state_vector,
)
from vecu.plant.drive import Drive, LongitudinalPart
from vecu.plant.manifold import EventsAhead, ManifoldPlantConfig
from vecu.plant.part import PlantPart, Send
from vecu.plant.throttle import ThrottlePart
from vecu.rng import rng_streams
from vecu.units import DEG_PER_RAD, KELVIN_AT_0_DEGC, MG_PER_KG

log = logging.getLogger(__name__)


class ManifoldPart:
    """Engine intake (Dutka 2006), once per engine event (Ts = 120 / (8 N)): ENG_Event (counter,
    N, setpoint, angle, MAP) and ENG_Intake (IAT); N and the setpoint are the drive's."""

    truth_message = "TRUTH_Manifold"  # its truth frame (dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "manifold"

    def __init__(self, codec: DbcCodec, seed: int,
                 config: ManifoldPlantConfig = ManifoldPlantConfig(),
                 drive: Drive | None = None) -> None:
        self._ev = codec["ENG_Event"]
        self._engine = engine = config.engine
        self._iat = codec["ENG_Intake"]
        self._ev_frame = self._ev.framer(("ENG_EventCounter", "ENG_Speed", "ENG_ThrottleSetpoint",
                                          "ENG_ThrottleAngle", "ENG_MAP"))
        self._iat_frame = self._iat.framer(("ENG_IntakeCounter", "ENG_IAT"))
        self.drive = drive if drive is not None else Drive(seed, engine=engine)
        self._profile_index = 0
        self._profile = self.drive.leg(0).profile
        self._t0_ns = 0
        n0, sp0 = self._profile.at(0.0)
        rng = rng_streams(seed, ("manifold.plant",))["manifold.plant"]
        x0 = steady_state_vector(nominal_input(sp0, n0, engine), engine)
        self._ahead = EventsAhead(engine, config, rng, x0)  # the events, in blocks
        self._ahead.start_profile(self._profile)
        self._rows: list[list[float]] = []
        self._times: list[int] = []
        self._i = 0
        self.events = 0
        self.truth_msg = None  # TRUTH_Manifold codec when recording truth
        # truth of the events so far (absolute event index -> P_im kPa, T_im K, CAC kg)
        self.truth: dict[int, tuple[float, float, float]] = {}

    def _next_profile(self) -> None:
        """The next leg's profile, continuing from the current state, where the last one ended."""
        self._profile_index += 1
        leg = self.drive.leg(self._profile_index)
        self._profile = leg.profile
        self._t0_ns = leg.start * round(self.drive.dt_s * NS_PER_S)
        self._ahead.start_profile(self._profile)

    def _from_ahead(self, t_ns: int) -> tuple[float, ...]:
        """The event at t_ns from the events computed ahead (EventsAhead), refilled as needed."""
        ahead = self._ahead
        i = self._i
        if i >= len(self._rows):
            k = ahead.fill(t_ns, self._t0_ns)
            while k == 0:  # the profile ends before t_ns
                self._next_profile()
                k = ahead.fill(t_ns, self._t0_ns)
            self._rows = ahead.out[:k].tolist()
            self._times = [*ahead.times[:k].tolist(), ahead.next_ns]
            i = 0
        if self._times[i] != t_ns:
            raise RuntimeError(f"manifold plant: event at {t_ns} ns, computed for "
                               f"{self._times[i]} ns")
        self._i = i + 1
        return (*self._rows[i], self._times[i + 1])

    def event(self, t_ns: int, send: Send) -> int:
        """One engine event at t_ns; returns the time of the next one."""
        n, sp, ta, p_kpa, t_meas, p_true, t_true, cac_true, next_ns = self._from_ahead(t_ns)
        k = self.events
        self.truth[k] = (p_true, t_true, cac_true)
        self.truth.pop(k - 64, None)  # bounded: probes look back a few events only
        ts = t_ns / NS_PER_S
        send(self._ev_frame(ts, k & 0xFF, n, sp * DEG_PER_RAD, ta * DEG_PER_RAD, p_kpa)[0])
        send(self._iat_frame(ts, k & 0xFF, t_meas - KELVIN_AT_0_DEGC)[0])
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_EventCounter": k & 0xFF, "TRU_MAP": p_true,
                                       "TRU_IMT": t_true - KELVIN_AT_0_DEGC, "TRU_CAC": cac_true * MG_PER_KG}, ts))
        self.events += 1
        return next_ns


class PlantNode(BusNode):
    """Runs its parts at their rates from a 1 ms base tick; acts on FI_Command frames."""

    def __init__(self, bus: can.BusABC, codec: DbcCodec, injector: FaultInjector,
                 parts: list[PlantPart], drive: Drive | None = None,
                 manifold: ManifoldPart | None = None) -> None:
        """parts run from the 1 ms tick; manifold (the engine-event part) from the scheduler's
        engine-event chain (engine_event)."""
        super().__init__(bus, "plant")
        self.injector = injector
        self.parts = parts
        self._fi = codec["FI_Command"]
        self._fi_key = (self._fi.frame_id, self._fi.is_extended)
        injector.bind(codec)
        self._fi_event = codec["FI_Event"] if "FI_Event" in codec else None  # noqa: SIM401 (no .get)
        self._codec = codec
        self._announced = 0  # injector events already sent as FI_Event frames
        self.frames_received = 0
        self.throttle = next((p for p in parts if isinstance(p, ThrottlePart)), None)
        self.longitudinal = next((p for p in parts if isinstance(p, LongitudinalPart)), None)
        self.manifold = manifold  # the engine-event chain's part (None: no engine events)
        self.drive = drive  # the car's motion all parts read (vecu.plant.drive)

    @property
    def consumed_ids(self) -> frozenset[tuple[int, bool]]:
        """The (CAN ID, extended) keys the plant acts on: FI_Command."""
        return frozenset({self._fi_key})

    def enable_truth(self, codec: DbcCodec) -> None:
        """Send the debug truth frames of dbc/vecu_truth.dbc next to each part's sensor frames."""
        for part in [*self.parts, self.manifold]:
            name = getattr(part, "truth_message", None)  # a part's class names its truth frame
            if name is not None:
                part.truth_msg = codec[name]

    def engine_event(self, t_ns: int) -> int | None:
        """Scheduler.chain task: one engine event of the manifold part, if there is one."""
        if self.manifold is None:
            return None
        return self.manifold.event(
            t_ns, self._send_via_faults if self.injector.frame_stage_active else self.send)

    def tick(self, t_ns: int) -> None:
        inj = self.injector
        inj.now_ns = t_ns
        self._poll_commands(t_ns)
        if len(inj.events) != self._announced:
            self._announce_faults()
        send = self._send_via_faults if inj.frame_stage_active else self.send
        for part in self.parts:
            if t_ns % part.period_ns == 0:
                part.tick(t_ns, send)
        if inj.frame_stage_active:
            for msg in inj.per_tick(t_ns):
                self.send(msg)

    def _send_via_faults(self, msg: can.Message) -> bool:
        """Send stage while frame faults are active: the injector transforms, drops, delays or
        repeats each outgoing frame (vecu.faults)."""
        for out in self.injector.process(msg):
            self.send(out)
        return True

    def _announce_faults(self) -> None:
        """One FI_Event frame (dbc/vecu.dbc) per fault start / end, so a trace carries them."""
        events = self.injector.events
        new, self._announced = events[self._announced:], len(events)
        if self._fi_event is None:
            return
        for ev in new:
            for kind, active in ([(ev.kind, 1)] if not ev.cleared and ev.kind != 0
                                 else [(k, 0) for k in ev.cleared] or [(ev.kind, 0)]):
                self.send(self._fi_event.frame(fault_event_signals(
                    self._codec, ev.target, int(kind), active, ev.source, ev.value),
                    ev.t_ns / NS_PER_S))

    def _poll_commands(self, t_ns: int) -> None:
        """Read the receive queue, at most rx_budget frames per tick (the rest shed, FI_Command
        frames among them kept); act on FI_Command, ignore everything else."""
        recv = self.bus.recv
        n = self.rx_budget.frames_per_tick
        while (msg := recv(0.0)) is not None:
            self._take(msg, t_ns)
            n -= 1
            if not n:  # past the budget: FI_Command frames still obeyed, the rest shed
                self.shed(lambda m: self._take(m, t_ns))
                break
        else:
            self.rx_saturated = 0

    def _take(self, msg: can.Message, t_ns: int) -> bool:
        """One received frame (counted): True when it is an FI_Command (obeyed or rejected)."""
        self.frames_received += 1
        if (msg.arbitration_id, msg.is_extended_id) != self._fi_key:
            return False
        if len(msg.data) != self._fi.length or msg.is_remote_frame:
            self.injector.rejected_commands += 1
            return True
        try:
            values = self._fi.decode(msg.data)
            obeyed = self.injector.on_command(t_ns, values["FI_Target"], values["FI_Kind"],
                                              values["FI_Value"])
        except Exception as exc:  # noqa: BLE001 - the handler boundary: counted
            self.injector.rejected_commands += 1
            self.handler_failed("FI_Command", exc)
            return True
        if not obeyed:
            log.warning("plant: rejected FI_Command %s", values)
        return True
