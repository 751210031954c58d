"""The XCP slave on CAN, attached to the ECU node (as the UDS server is): commands on
CAN_ID_MASTER, responses, events and DAQ DTOs on CAN_ID_SLAVE (classic CAN, 8 bytes).

EcuNode hands it every frame on its IDs (on_frame) and calls tick() once per 1 ms base tick,
after the functions have broadcast: at most `commands_per_tick` commands are answered, then the
running DAQ lists whose event fired are sampled (the values of this tick) and sent, at most
`daq_frames_per_tick` DTOs. Time is the tick's, so on the simulated clock the same commands give
the same responses, calibrations and samples at the same times.

Nothing a master sends raises out of tick(): the command handler and the DAQ sampler run behind
one boundary (`Boundary`). A refused command is its XCP error packet (commands.py); an error
the handler did not foresee is ERR_GENERIC (0x31) to the master, and a DAQ entry that cannot be
read drops its DTO (`odts_dropped`); either is counted per kind (`xcp.internal_errors` in the
summary) and logged once per kind, and the node goes on ticking.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import can
import numpy as np

from vecu.clock import NS_PER_S
from vecu.ecu.node import EcuNode
from vecu.params import ParamError
from vecu.xcp.calibration import Calibrator
from vecu.xcp.commands import ERR, ERR_GENERIC, CommandProcessor
from vecu.xcp.config import XcpConfig
from vecu.xcp.daq import Daq
from vecu.xcp.measurements import ecu_measurements
from vecu.xcp.memory import CalSegment
from vecu.xcp.security import SeedKey

log = logging.getLogger(__name__)
INBOX_FACTOR = 8  # frames kept waiting: this many ticks' worth of commands


class Boundary:
    """Errors that reached the slave's boundary: counted per kind ("where: ExceptionType"),
    the first of each kind logged with its traceback (a bug to report), none raised."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def caught(self, where: str, exc: BaseException) -> None:
        kind = f"{where}: {type(exc).__name__}"
        n = self.counts.get(kind, 0)
        if not n:
            log.error("xcp %s: %s (counted in the summary's xcp.internal_errors, logged once)",
                      kind, exc, exc_info=exc)
        self.counts[kind] = n + 1


class XcpServer:
    """The XCP slave of `node` (attach with node.attach(server))."""

    def __init__(self, node: EcuNode, config: XcpConfig, ecu_tree: Any, reference_tree: Any,
                 rng: np.random.Generator, validate: Callable[[Any], None] | None = None) -> None:
        self.node = node
        self.cfg = config
        self.ids = frozenset({(config.master_id, False), (config.slave_id, False)})
        self.calibrator = Calibrator(node, ecu_tree, validate)
        self.segment = CalSegment(ecu_tree, self.calibrator.is_live)
        self.measurements = ecu_measurements(node)
        self.daq = Daq(config)
        self.proc = CommandProcessor(config, self.segment, self.calibrator, reference_tree,
                                     self.measurements, self.daq,
                                     SeedKey(config.seed_key, config.secret, rng), self.a2l)
        self._a2l: str | None = None
        self._inbox: deque[bytes] = deque()
        self._inbox_max = INBOX_FACTOR * config.commands_per_tick
        self.frames_dropped = 0
        self.echoes = 0
        self.responses = 0
        self.boundary = Boundary()
        self.daq.on_read_error = lambda exc: self.boundary.caught("daq sample", exc)
        self._manifold = node.function("manifold")
        self._events_seen = 0
        self._ts = 0.0

    def a2l(self) -> str:
        """The A2L of this slave (GET_ID type 4 uploads it)."""
        if self._a2l is None:
            from vecu.xcp.a2l import render_a2l

            self._a2l = render_a2l(self.cfg, self.segment, self.measurements,
                                   self.calibrator.tree)
        return self._a2l

    # ------------------------------------------------------------- node side
    def on_frame(self, msg: can.Message, t_ns: int) -> None:
        if msg.arbitration_id == self.cfg.slave_id:
            self.echoes += 1
        elif len(self._inbox) >= self._inbox_max:
            self.frames_dropped += 1
        else:
            self._inbox.append(bytes(msg.data))

    def _send(self, data: bytes) -> bool:
        return self.node.send(can.Message(arbitration_id=self.cfg.slave_id, data=data,
                                          is_extended_id=False, timestamp=self._ts))

    def tick(self, t_ns: int) -> None:
        self._ts = t_ns / NS_PER_S
        inbox = self._inbox
        if inbox:
            handle = self.proc.handle
            for _ in range(min(len(inbox), self.cfg.commands_per_tick)):
                cto = inbox.popleft()
                try:
                    packets = handle(cto, t_ns)
                except Exception as exc:  # noqa: BLE001 - the boundary: answered, never raised
                    self.boundary.caught(f"command 0x{cto[0]:02X}", exc)
                    packets = [bytes([ERR, ERR_GENERIC])]
                for packet in packets:
                    self.responses += self._send(packet)
        man = self._manifold
        engine = False
        if man is not None and man.events != self._events_seen:  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            self._events_seen = man.events  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            engine = True
        if self.daq.running:
            try:
                self.daq.sample(t_ns, engine, self._send)
            except Exception as exc:  # noqa: BLE001 - the boundary: counted, never raised
                self.boundary.caught("daq sample", exc)

    def check_calibration(self, sets: list[tuple[str, Any]]) -> Any:
        """The working tree with (path under ecu., value) pairs, checked; ParamError for a
        value out of bounds or a leaf the running ECU does not take."""
        for path, _ in sets:
            if not self.calibrator.is_live(path):
                raise ParamError(f"parameter 'ecu.{path}' is not calibratable mid-run (the "
                                 f"ECU takes it at start: use --set)")
        return self.calibrator.check(sets, self.proc.working_tree)

    def calibrate(self, sets: list[tuple[str, Any]], t_ns: int) -> None:
        """A timed set: as an XCP write of the same values in the tick at t_ns."""
        self.proc.take(self.check_calibration(sets), t_ns)

    def summary(self) -> dict[str, Any]:
        """For the run summary: counters and the calibrations taken."""
        return {**asdict(self.proc.stats), **asdict(self.daq.stats),
                "values_saturated": self.measurements[0].stats.saturated
                if self.measurements else 0,
                "internal_errors": dict(sorted(self.boundary.counts.items())),
                "responses": self.responses, "frames_dropped": self.frames_dropped,
                "connected": self.proc.connected,
                "calibrations_taken": [[t / NS_PER_S, "ecu." + p, v]
                                       for t, p, v in self.calibrator.changes]}


def attach_xcp(node: EcuNode, config: XcpConfig, ecu_tree: Any, reference_tree: Any, seed: int,
               validate: Callable[[Any], None] | None = None) -> XcpServer | None:
    """Serve XCP on `node` (None when ecu.xcp.enabled is false); seeds come from the run's
    seed (the named stream 'xcp.security'); reference_tree: the reference page (defaults)."""
    if not config.enabled:
        return None
    from vecu.rng import rng_streams

    server = XcpServer(node, config, ecu_tree, reference_tree,
                       rng_streams(seed, ("xcp.security",))["xcp.security"], validate)
    node.attach(server)
    return server
