"""Plant node: steps the throttle body every 1 ms and puts its sensor frames on the bus."""

from __future__ import annotations

import logging

import can

from vecu.calibration import TpsCalibration
from vecu.clock import NS_PER_S
from vecu.codec import DbcCodec
from vecu.faults import FaultInjector, FaultTarget
from vecu.node import BusNode
from vecu.plant.throttle import InputGenerator, ThrottlePlant

log = logging.getLogger(__name__)

TPS_V_MIN, TPS_V_MAX = 0.0, 5.0  # sensor output saturates at ground and supply


class ThrottlePlantNode(BusNode):
    """Sends TPS_Sensor (E2E) and ETB_Wattmeter each tick; obeys FI_Command frames.

    Per tick k: u_k from the input generator, y_k and the TPS voltage measured on x_k, faults
    applied, frames sent with timestamp t_k, then x_{k+1} = f(x_k, u_k) + F w_k (eq. 3).
    """

    def __init__(self, bus: can.BusABC, codec: DbcCodec, plant: ThrottlePlant,
                 inputs: InputGenerator, injector: FaultInjector,
                 calibration: TpsCalibration = TpsCalibration()) -> None:
        super().__init__(bus, "plant")
        self.plant = plant
        self.inputs = inputs
        self.injector = injector
        self.calibration = calibration
        self._tps = codec["TPS_Sensor"]
        self._watt = codec["ETB_Wattmeter"]
        self._fi = codec["FI_Command"]
        self._fi_key = (self._fi.frame_id, self._fi.is_extended)
        self._counter = 0
        self.frames_received = 0
        # truth of the last tick, read by probes
        self.theta = 0.0
        self.u = 0.0
        self.tps_voltage: float | None = None

    def tick(self, t_ns: int) -> None:
        self._poll_commands(t_ns)
        plant = self.plant
        u = self.inputs.next()
        y = plant.wattmeter()
        v_true = plant.tps_voltage(self.calibration)
        v = self.injector.apply(FaultTarget.TPS, v_true)
        ts = t_ns / NS_PER_S
        if v is not None:
            v = TPS_V_MIN if v < TPS_V_MIN else (TPS_V_MAX if v > TPS_V_MAX else v)
            self._send(self._tps.frame(
                {"TPS_CRC": 0, "TPS_AliveCounter": self._counter, "TPS_Voltage": v}, ts))
            self._counter = (self._counter + 1) & 0xF
        self._send(self._watt.frame({"ETB_Voltage": u, "ETB_Power": y}, ts))
        self.theta = plant.theta
        self.u = u
        self.tps_voltage = v
        plant.step(u)

    def _poll_commands(self, t_ns: int) -> None:
        """Drain the receive queue; act on FI_Command, ignore everything else."""
        recv = self.bus.recv
        while (msg := recv(0.0)) is not None:
            self.frames_received += 1
            if (msg.arbitration_id, msg.is_extended_id) != self._fi_key:
                continue
            if len(msg.data) != self._fi.length or msg.is_remote_frame:
                self.injector.rejected_commands += 1
                continue
            values = self._fi.decode(msg.data)
            if not self.injector.on_command(t_ns, values["FI_Target"], values["FI_Kind"],
                                            values["FI_Value"]):
                log.warning("plant: rejected FI_Command %s", values)
