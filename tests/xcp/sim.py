"""A steppable simulated run with the ECU's XCP slave, and pyxcp as the master on its own
thread: the test steps the simulated clock 1 ms at a time while the master talks (as
tests/uds/sim.py does for udsoncan). pyxcp reads the bus with its own threads, so the master
stands on a python-can `virtual` bus of the run's channel."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from pyxcp.config import create_application_from_config
from pyxcp.master import Master

from tests.uds.sim import SimRun, run_stepped
from vecu.assembly import TICK_NS
from vecu.config import RunConfig
from vecu.runner import attach_xcp_server
from vecu.xcp.server import XcpServer


def master_config(master_id: int = 0x7F0, slave_id: int = 0x7F1, channel: str = "",
                  timeout: float = 5.0, **general: Any) -> Any:
    """A pyxcp application for XCP on CAN with these IDs (error handling off: a refused
    command raises XcpResponseError at once instead of pyxcp's retries)."""
    app = create_application_from_config({
        "Transport": {"CAN": {"interface": "virtual", "channel": channel,
                              "can_id_master": master_id, "can_id_slave": slave_id}},
        "General": {"disable_error_handling": True, "connect_retries": 0, **general},
    }, log_level=logging.WARNING)
    app.transport.layer = "CAN"
    app.transport.timeout = timeout
    return app


class XcpSim(SimRun):
    """Plant and ECU (UDS and XCP slaves) on a fresh virtual channel."""

    def __init__(self, config: RunConfig | None = None) -> None:
        super().__init__(config)
        server = attach_xcp_server(self.ecu, self.config)
        assert server is not None
        self.xcp: XcpServer = server

    def master(self, policy: Any = None, timeout: float = 5.0, **general: Any) -> Master:
        cfg = self.config.params.ecu.xcp
        app = master_config(cfg.master_id, cfg.slave_id, self.channel, timeout, **general)
        return Master("can", config=app, policy=policy, transport_layer_interface=self.bus())

    def serve(self, work: Callable[[Master], Any], max_sim_s: float = 120.0,  # type: ignore[override]  # a pyxcp Master, not a udsoncan Client
              pace_s: float = 0.0002, policy: Any = None, timeout: float = 5.0,
              **general: Any) -> Any:
        """Run `work(master)` on a thread while the simulated clock steps 1 ms at a time;
        its result (or its exception)."""
        def body() -> Any:
            with self.master(policy, timeout, **general) as m:
                return work(m)

        # the master's listener thread up before the first response can come: settle 50 ms
        return run_stepped(body, self.step, round(max_sim_s * 1e9) // TICK_NS, pace_s,
                           settle_s=0.05, who="master")


class RawMaster:
    """Raw XCP frames on the run's channel, the simulated clock stepped by hand: send CTOs,
    step, and read what came back (the slave's packets) and which ticks the ECU broadcast its
    throttle estimate in (decoded from the bus)."""

    def __init__(self, sim: XcpSim) -> None:
        self.sim = sim
        self.bus = sim.bus()
        cfg = sim.config.params.ecu.xcp
        self.master_id, self.slave_id = cfg.master_id, cfg.slave_id
        self.estimate = sim.codec["ECU_ThrottleEstimate"]
        self.estimates: list[dict[str, float]] = []  # every ECU_ThrottleEstimate, decoded

    def send(self, *ctos: bytes) -> None:
        import can

        for cto in ctos:
            self.bus.send(can.Message(arbitration_id=self.master_id, data=cto,
                                      is_extended_id=False))

    def step(self, ticks: int = 1) -> list[bytes]:
        """Step the clock; the slave's packets sent meanwhile (DTOs included)."""
        out = []
        for _ in range(ticks):
            self.sim.step()
            while (msg := self.bus.recv(0.0)) is not None:
                if msg.arbitration_id == self.slave_id:
                    out.append(bytes(msg.data))
                elif msg.arbitration_id == self.estimate.frame_id:
                    self.estimates.append(self.estimate.decode(msg.data))
        return out

    def ask(self, cto: bytes, ticks: int = 1) -> list[bytes]:
        """One command, the clock stepped `ticks`: the slave's packets (DTOs included)."""
        self.send(cto)
        return self.step(ticks)
