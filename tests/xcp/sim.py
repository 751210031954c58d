"""A steppable simulated run with the ECU's XCP slave, and pyxcp as the master on its own
thread: the test steps the simulated clock 1 ms at a time while the master talks (as
tests/uds/sim.py does for udsoncan). pyxcp reads the bus with its own threads, so the master
stands on a python-can `virtual` bus of the run's channel."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from pyxcp.config import create_application_from_config
from pyxcp.master import Master

from tests.uds.sim import SimRun
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
        out: dict[str, Any] = {}

        def body() -> None:
            try:
                with self.master(policy, timeout, **general) as m:
                    out["result"] = work(m)
            except BaseException as exc:  # noqa: BLE001 - handed to the test
                out["error"] = exc

        thread = threading.Thread(target=body, daemon=True)
        thread.start()
        time.sleep(0.05)  # the master's listener thread up before the first response can come
        end = self.t_ns + round(max_sim_s * 1e9)
        while thread.is_alive() and self.t_ns < end:
            self.step()
            time.sleep(pace_s)
        thread.join(10.0)
        assert not thread.is_alive(), "the master did not finish"
        if "error" in out:
            raise out["error"]
        return out["result"]
