"""Plant node: the simulated vehicle on the bus, one part per physical system.

Each part steps its model at its own rate (a multiple of the 1 ms base tick) and sends its
sensor frames; the node owns the bus and obeys FI_Command frames for the fault injector.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Protocol

import can
import numpy as np

from vecu.bus import BusNode
from vecu.can_message import message
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.faults import FaultInjector, FaultTarget, fault_event_signals
from vecu.kernels import backend
from vecu.models.manifold import (
    cylinder_air_charge,
    nominal_input,
    sample_time,
    steady_state_vector,
)
from vecu.models.sensors import TpsCalibration
from vecu.plant.drive import Drive, Leg
from vecu.plant.input_file import BufferedInput
from vecu.plant.longitudinal import AccelSensorConfig, WheelSensorConfig
from vecu.plant.manifold import (
    EventsAhead,
    ManifoldPlant,
    ManifoldPlantConfig,
    compiled_tables,
)
from vecu.plant.throttle import ThrottlePlant, TicksAhead
from vecu.rng import rng_streams
from vecu.units import DEG_PER_RAD, KELVIN_AT_0_DEGC, MG_PER_KG, MPS_PER_KMH

log = logging.getLogger(__name__)

TPS_V_MIN, TPS_V_MAX = 0.0, 5.0  # sensor output saturates at ground and supply
HELD_PAYLOADS = 64  # TPS payloads of fault values kept (ThrottlePart._tps_faulted)
Send = Callable[[can.Message], bool]


_TPS = FaultTarget.TPS  # bound once (per-tick code)


class PlantPart(Protocol):
    name: str
    period_ns: int

    def tick(self, t_ns: int, send: Send) -> None: ...


class ThrottlePart:
    """Throttle body (Vargas 2015): TPS_Sensor (E2E) and ETB_Wattmeter every 1 ms.

    Per tick k: u_k from the input generator, y_k and the TPS voltage measured on x_k, faults
    applied, frames sent with timestamp t_k, then x_{k+1} = f(x_k, u_k) + F w_k (eq. 3).
    """

    truth_message = "TRUTH_Throttle"  # its truth frame (vecu/dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "throttle"
    period_ns = NS_PER_MS

    def __init__(self, codec: DbcCodec, plant: ThrottlePlant, inputs: BufferedInput,
                 injector: FaultInjector, calibration: TpsCalibration = TpsCalibration()) -> None:
        self.plant = plant
        self.inputs = inputs
        self.injector = injector
        self.calibration = calibration
        self._tps = codec["TPS_Sensor"]
        self._watt = codec["ETB_Wattmeter"]
        self._tps_frame = self._tps.framer(("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage"))
        self._modulo = self._tps.e2e.protection.counter_modulo  # P11: 0..14
        self._watt_frame = self._watt.framer(("ETB_Voltage", "ETB_Power"))
        self._counter = 0
        self.truth_msg = None  # TRUTH_Throttle codec when recording truth (PlantNode.enable_truth)
        # truth and sensor of the last tick, read by probes
        self.theta = 0.0
        self.u = 0.0
        self.tps_voltage: float | None = None
        # under the numba backend the ticks are computed ahead in blocks (same numbers), and
        # their frames encoded in blocks (FrameCodec.encode_rows, the framers' payloads)
        self._ahead = TicksAhead(plant, calibration) if backend() == "numba" else None
        self._rows: list[list[float]] = []
        self._us: list[float] = []
        self._k = 0
        self._tps_ahead: list[bytearray | None] = []  # payloads of the ticks ahead (None: make)
        self._watt_ahead: list[bytearray | None] = []
        self._counter_ahead = 0  # the TPS counter the first tick ahead was encoded with
        self._held: dict[tuple[float, int], bytes] = {}  # (voltage, counter) -> payload

    def _fill(self) -> None:
        """The next TicksAhead.AHEAD ticks: their rows and the payloads of their frames, the
        TPS frames encoded as if each tick sends one with the TPS left as it is."""
        assert self._ahead is not None
        self._us = us = self.inputs.take(TicksAhead.AHEAD)
        block = self._ahead.fill(us)
        self._rows = block.tolist()
        self._k = 0
        n = len(block)
        cols = block.T
        v = np.where(cols[2] < TPS_V_MIN, TPS_V_MIN, np.minimum(cols[2], TPS_V_MAX))
        self._counter_ahead = c0 = self._counter
        tps = self._tps.encode_rows(("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage"), (
            np.zeros(n), (c0 + np.arange(n)) % self._modulo, v))
        watt = self._watt.encode_rows(("ETB_Voltage", "ETB_Power"), (np.array(us), cols[1]))
        self._tps_ahead = _payload_list(tps, n)
        self._watt_ahead = _payload_list(watt, n)

    def _measure_and_step(self) -> tuple[float, float, float, float]:
        """(u_k, theta_k, y_k, TPS voltage_k) of this tick; the plant then steps with u_k."""
        plant = self.plant
        if self._ahead is None:
            u = self.inputs.next()
            theta, y = plant.theta, plant.wattmeter()
            v = plant.tps_voltage(self.calibration)
            plant.step(u)
            return u, theta, y, v
        k = self._k
        if k >= len(self._rows):
            self._fill()
            k = 0
        self._k = k + 1
        theta, y, v = self._rows[k]
        return self._us[k], theta, y, v

    def _tps_faulted(self, ts: float, v: float) -> can.Message:
        """The TPS frame of a fault's voltage v: the framer's; the payloads of a held value (a
        dead, stuck or shorted sensor) are kept per counter value, each encoded once (at most
        HELD_PAYLOADS kept)."""
        key = (v, self._counter)
        data = self._held.get(key)
        if data is None:
            msg = self._tps_frame(ts, 0, self._counter, v)
            if len(self._held) >= HELD_PAYLOADS:
                self._held.clear()
            self._held[key] = bytes(msg.data)
            return msg
        return message(ts, self._tps.frame_id, self._tps.is_extended, bytearray(data),
                       self._tps.is_fd)

    def tick(self, t_ns: int, send: Send) -> None:
        u, theta, y, v_sensor = self._measure_and_step()
        v = self.injector.apply(_TPS, v_sensor)
        ts = t_ns / NS_PER_S
        k = self._k - 1  # this tick's payloads ahead (if any)
        if v is not None:
            data = (self._tps_ahead[k] if 0 <= k < len(self._tps_ahead) and v is v_sensor
                    and self._counter == (self._counter_ahead + k) % self._modulo else None)
            faulted = v is not v_sensor
            v = TPS_V_MIN if v < TPS_V_MIN else (min(v, TPS_V_MAX))
            if data is not None:  # encoded from the same clamped voltage
                send(message(ts, self._tps.frame_id, self._tps.is_extended, data, self._tps.is_fd))
            elif faulted:
                send(self._tps_faulted(ts, v))
            else:
                send(self._tps_frame(ts, 0, self._counter, v))
            self._counter = (self._counter + 1) % self._modulo
        data = self._watt_ahead[k] if 0 <= k < len(self._watt_ahead) else None
        if data is not None:
            send(message(ts, self._watt.frame_id, self._watt.is_extended, data, self._watt.is_fd))
        else:
            send(self._watt_frame(ts, u, y))
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_ThrottleAngle": theta, "TRU_MotorVoltage": u}, ts))
        self.theta = theta
        self.u = u
        self.tps_voltage = v


def _payload_list(encoded: tuple[np.ndarray, np.ndarray] | None, n: int
                  ) -> list[bytearray | None]:
    """Per row its payload (a fresh bytearray, each sent once), None where the row is left to
    the framer (or every row, without a block encoding)."""
    if encoded is None:
        return [None] * n
    payloads, left = encoded
    size = payloads.shape[1]
    blob = payloads.tobytes()
    out: list[bytearray | None] = [bytearray(blob[i:i + size]) for i in range(0, n * size, size)]
    for i in np.flatnonzero(left).tolist():
        out[i] = None
    return out


class LongitudinalPart:
    """Longitudinal vehicle (Hernandez 2005): ESC_Motion (wheel speed, accelerometer) every 2 ms.

    Sends the sensors of the drive's manoeuvres (vecu.plant.drive: the paper's 84 km/h ->
    standstill braking first, then a launch-and-brake cycle and road legs), sample t_ns / 2 ms
    of the drive at each tick; without a drive it makes its own from seed and sequence.
    """

    truth_message = "TRUTH_Speed"  # its truth frame (vecu/dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "longitudinal"
    period_ns = 2 * NS_PER_MS

    def __init__(self, codec: DbcCodec, seed: int, sequence: tuple[str, ...] | None = None,
                 wheel: WheelSensorConfig = WheelSensorConfig(),
                 accel: AccelSensorConfig = AccelSensorConfig(), drive: Drive | None = None) -> None:
        self._msg = codec["ESC_Motion"]
        self._frame = self._msg.framer(("ESC_WheelSpeed", "ESC_LongAccel"))
        self.drive = drive if drive is not None else Drive(seed, sequence, wheel, accel)
        self._cols: tuple[list[float], ...] = ()
        self._payloads: list[bytearray | None] = []
        self._leg = leg = self.drive.leg_at(0)
        self._enter(leg)
        self.truth_msg = None  # TRUTH_Speed codec when recording truth
        self.v = self.a = self.wheel = self.accel = 0.0  # truth and raw sensors of the last tick (SI)

    def _enter(self, leg: Leg) -> None:
        self._leg = leg
        trace = leg.trace
        self._cols = (trace.v.tolist(), trace.a.tolist(), trace.wheel.tolist(),
                      trace.accel.tolist())
        # the whole manoeuvre's ESC_Motion payloads at once (FrameCodec.encode_rows: the
        # framer's payloads); rows it leaves (none for finite sensors) go to the framer
        encoded = self._msg.encode_rows(("ESC_WheelSpeed", "ESC_LongAccel"),
                                        (trace.wheel / MPS_PER_KMH, trace.accel))
        self._payloads = _payload_list(encoded, len(trace.v))

    def tick(self, t_ns: int, send: Send) -> None:
        k = t_ns // self.period_ns
        leg = self._leg
        if not leg.start <= k < leg.end:
            leg = self.drive.leg_at(k)
            self._enter(leg)
        i = k - leg.start
        cols = self._cols
        v, a, wheel, accel = cols[0][i], cols[1][i], cols[2][i], cols[3][i]
        self.v, self.a, self.wheel, self.accel = v, a, wheel, accel
        ts = t_ns / NS_PER_S
        data = self._payloads[i]
        if data is not None:
            send(message(ts, self._msg.frame_id, self._msg.is_extended, data, self._msg.is_fd))
        else:
            send(self._frame(ts, wheel / MPS_PER_KMH, accel))
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_VehSpeed": v / MPS_PER_KMH, "TRU_VehAccel": a}, ts))


class ManifoldPart:
    """Engine intake (Dutka 2006) stepped once per engine event, Ts = 120 / (8 N): sends
    ENG_Event (counter, N, throttle setpoint and angle, MAP) and ENG_Intake (IAT) at each event.
    The engine speed and throttle setpoint are the drive's (vecu.plant.drive: the driveline
    behind the car's speed), one leg's profile after the other on the drive's clock."""

    truth_message = "TRUTH_Manifold"  # its truth frame (vecu/dbc/vecu_truth.dbc; PlantNode.enable_truth)
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
        self.plant = ManifoldPlant(engine, config, rng, x0)
        # under the numba backend the events are computed ahead in blocks (same numbers)
        self._ahead = self._events_ahead(config, rng, x0)
        self._rows: list[list[float]] = []
        self._times: list[int] = []
        self._i = 0
        self.events = 0
        self.truth_msg = None  # TRUTH_Manifold codec when recording truth
        # truth of the events so far (absolute event index -> P_im kPa, T_im K, CAC kg)
        self.truth: dict[int, tuple[float, float, float]] = {}

    def _events_ahead(self, config: ManifoldPlantConfig, rng: np.random.Generator,
                      x0: np.ndarray) -> EventsAhead | None:
        if backend() != "numba" or not EventsAhead.usable(self._profile):
            return None
        tables = compiled_tables(self._engine)
        if tables is None:
            return None
        ahead = EventsAhead(self._engine, config, rng, x0, tables)
        ahead.start_profile(self._profile)
        return ahead

    def _next_profile(self) -> None:
        """The next leg's profile, continuing from the current state, where the last one ended."""
        self._profile_index += 1
        leg = self.drive.leg(self._profile_index)
        self._profile = leg.profile
        self._t0_ns = leg.start * round(self.drive.dt_s * NS_PER_S)
        if self._ahead is not None:
            if EventsAhead.usable(self._profile):
                self._ahead.start_profile(self._profile)
            else:  # (not for drive profiles) go on stepping ManifoldPlant from here
                self.plant.x = self._ahead.state.tolist()
                self._ahead = None

    def _step(self, t_ns: int) -> tuple[float, ...]:
        """One event stepped by ManifoldPlant: (N, TA_SP, the TA, P_im and T_im.out readings,
        the truth's P_im, T_im and CAC, the next event's time)."""
        t_s = (t_ns - self._t0_ns) / NS_PER_S
        while t_s >= self._profile.duration_s:
            self._next_profile()
            t_s = (t_ns - self._t0_ns) / NS_PER_S
        n, sp = self._profile.at(t_s)
        plant = self.plant
        ta, p_kpa, t_meas = plant.measure()
        p_true, t_true = plant.p_im, plant.t_im
        cac_true = cylinder_air_charge(p_true, t_true, n, self._engine)
        dt = sample_time(n, self._engine.n_cyl)
        plant.step(nominal_input(sp, n, self._engine), dt)
        return (n, sp, ta, p_kpa, t_meas, p_true, t_true, cac_true,
                t_ns + max(1, round(dt * NS_PER_S)))

    def _from_ahead(self, t_ns: int) -> tuple[float, ...]:
        """The event at t_ns from the events computed ahead (EventsAhead), refilled as needed."""
        ahead = self._ahead
        assert ahead is not None
        i = self._i
        if i >= len(self._rows):
            k = ahead.fill(t_ns, self._t0_ns)
            while k == 0:  # the profile ends before t_ns
                self._next_profile()
                if self._ahead is None:
                    return self._step(t_ns)
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
        n, sp, ta, p_kpa, t_meas, p_true, t_true, cac_true, next_ns = (
            self._from_ahead(t_ns) if self._ahead is not None else self._step(t_ns))
        k = self.events
        self.truth[k] = (p_true, t_true, cac_true)
        self.truth.pop(k - 64, None)  # bounded: probes look back a few events only
        ts = t_ns / NS_PER_S
        send(self._ev_frame(ts, k & 0xFF, n, sp * DEG_PER_RAD, ta * DEG_PER_RAD, p_kpa))
        send(self._iat_frame(ts, k & 0xFF, t_meas - KELVIN_AT_0_DEGC))
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
        """Send the debug truth frames of vecu/dbc/vecu_truth.dbc next to each part's sensor frames."""
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
        """One FI_Event frame (vecu/dbc/vecu.dbc) per fault start / end, so a trace carries them."""
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
