"""The diagnostic faults of one ECU: a hook on its UDS server (vecu.uds.server.UdsServer.hook)
that changes the response path, the flow control of a request, or the frames of a response, as
the catalogue's record says. With no fault active the server's normal path (can-isotp) runs
untouched; the ECU goes on estimating and broadcasting whatever the fault.

Every start and end is an FI_Event frame (FI_EvKind 31, vecu.uds.diag_faults.catalogue)."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import can

from vecu.clock import NS_PER_MS
from vecu.uds.diag_faults.catalogue import PENDING_INTERVAL_MS, WAIT_INTERVAL_MS
from vecu.uds.diag_faults.isotp_frames import (
    SegmentedSender,
    fd_single_frame,
    flow_control,
    frame,
)
from vecu.uds.diag_faults.schedule import FaultSchedule
from vecu.uds.diag_faults.setting import DiagFaultSetting

if TYPE_CHECKING:
    from vecu.uds.server import UdsServer

_MS = NS_PER_MS
# faults set through can-isotp's own parameters of the ECU's physical endpoint
_PARAMS = {"fc_stmin": "stmin", "fc_blocksize": "blocksize", "padding_byte": "tx_padding"}
_RAW_TX = {"cf_wrong_sn", "cf_repeated_sn", "cf_missing", "ff_bad_length", "ff_escape32",
           "sf_during_rx", "ff_during_rx"}


def _is_first(msg: can.Message, pci: int) -> bool:
    return len(msg.data) > 0 and msg.data[0] >> 4 == pci


class EcuDiagFaults:
    """Attach with `attach_diag_faults(server, settings)`. Also a DiagnosticServer of the node
    for the flow control frames to the extra responders of the functional faults."""

    def __init__(self, server: UdsServer, settings: Sequence[DiagFaultSetting],
                 source: str = "api") -> None:
        self.server = server
        self.node = server.node
        self.cfg = server.cfg
        codec = self.node.codec
        fi = codec["FI_Event"] if "FI_Event" in codec else None  # noqa: SIM401 (no .get)
        self.schedule = FaultSchedule(settings, self.cfg.response_id, fi, self.node.send, source)
        self.settings = self.schedule.settings
        self.current: DiagFaultSetting | None = None
        self._due: list[tuple[int, int, Callable[[int], None]]] = []
        self._seq = itertools.count()
        self._senders: dict[int, SegmentedSender] = {}  # FC ID -> sender
        self._held = False
        self._busy_sent = 0
        self._generation = 0  # a new request ends the previous request's scheduled actions
        extra = max((int(s.value) if s.fault.name == "functional_multi" else 1)
                    for s in self.settings if s.fault.name.startswith("functional_")) \
            if any(s.fault.name.startswith("functional_") for s in self.settings) else 0
        self.ids = frozenset((self.cfg.request_id + k, False) for k in range(1, extra + 1))
        self._defaults = {p: getattr(server.phys.layer.params, p) for p in _PARAMS.values()}

    # ------------------------------------------------------------ node / server side
    def on_frame(self, msg: can.Message, t_ns: int) -> None:
        """Flow control to an extra responder (this object's ids)."""
        sender = self._senders.get(msg.arbitration_id)
        if sender is not None:
            sender.on_fc(bytes(msg.data), t_ns)

    def tick(self, t_ns: int) -> None:
        """The node's call; the work is done in poll(), from the UDS server's tick."""

    def take(self, msg: can.Message, t_ns: int) -> bool:
        """A frame on the server's IDs; True when the fault took it (not for can-isotp)."""
        cfg = self.cfg
        cid = msg.arbitration_id
        if cid == cfg.response_id:
            return False
        sender = self._senders.get(cid)
        if sender is not None and _is_first(msg, 3):
            sender.on_fc(bytes(msg.data), t_ns)
            return True
        if not (_is_first(msg, 0) or _is_first(msg, 1)):
            return False
        self._generation += 1
        self._choose(t_ns, new_request=True)
        cur = self.current
        if cur is None or cid != cfg.request_id or not _is_first(msg, 1) \
                or cur.fault.layer != "isotp-rx":
            return False
        return self._request_fault(cur, msg, t_ns)

    def _request_fault(self, cur: DiagFaultSetting, msg: can.Message, t_ns: int) -> bool:
        name, v = cur.fault.name, int(cur.value)
        fc = self._raw
        if name in ("fc_wait", "fc_wait_excess"):
            for k in range(v):
                self._at(t_ns + round(k * WAIT_INTERVAL_MS * _MS), fc(flow_control(1)))
            self._at(t_ns + round(v * WAIT_INTERVAL_MS * _MS), self._deliver(msg))
        elif name == "fc_overflow":
            fc(flow_control(2))(t_ns)
        elif name == "fc_invalid_fs":
            fc(flow_control(v))(t_ns)
        elif name == "fc_late":
            self._at(t_ns + round(v * _MS), self._deliver(msg))
        elif name == "fc_never":
            pass
        else:
            return False  # fc_stmin / fc_blocksize: can-isotp's parameters (_choose)
        return True

    def respond(self, request: bytes, functional: bool, response: bytes | None,
                t_ns: int) -> bytes | None:
        """The response the server sends now through can-isotp (None: nothing now)."""
        cur = self.current
        suppressed, self.server.suppressed = self.server.suppressed, None
        if cur is None or cur.fault.layer in ("isotp-rx", "doip"):
            return response
        name, v = cur.fault.name, cur.value
        sid = request[0] if request else 0
        pending = bytes([0x7F, sid, 0x78])
        if name == "spr_answered":
            return response if response is not None else suppressed
        if name.startswith("functional_"):
            if functional and response is not None:
                self._extra_responders(cur, response, t_ns)
            return response
        if response is None:
            return None
        if name == "pending":
            for k in range(1, int(v)):
                self._at(t_ns + round(k * PENDING_INTERVAL_MS * _MS), self._payload(pending))
            self._at(t_ns + round(v * PENDING_INTERVAL_MS * _MS), self._payload(response))
            return pending
        if name == "pending_forever":
            self._repeat_pending(pending, t_ns)
            return pending
        if name in ("late_p2", "early_p2"):
            self._at(t_ns + round(v * _MS), self._payload(response))
            return None
        if name == "late_p2star":
            self._at(t_ns + round(v * _MS), self._payload(response))
            return pending
        if name == "no_response":
            return None
        if name == "busy_repeat":
            if self._busy_sent < v:
                self._busy_sent += 1
                return bytes([0x7F, sid, 0x21])
            return response
        positive = response[0] != 0x7F
        if name == "wrong_sid" and positive:
            return bytes([response[0] ^ 0x01]) + response[1:]
        if name == "truncated" and positive:
            return response[:max(1, len(response) - int(v))]
        if name == "overlong" and positive:
            return response + bytes(int(v))
        if name == "unsolicited":
            self._at(t_ns + round(v * _MS), self._raw(bytes([0x02, 0x7E, 0x00])))
            return response
        if name == "canfd_frame":
            self.node.send(frame(self.cfg.response_id, fd_single_frame(response), t_ns, None,
                                 fd=True))
            return None
        if name in _RAW_TX and len(response) > 7:
            self._senders[self.cfg.request_id] = SegmentedSender(
                response, self.cfg.response_id, self.node.send, cur.fault, v, t_ns)
            return None
        return response

    def poll(self, t_ns: int) -> None:
        """Once per tick, before the server takes frames in: due actions, senders, windows."""
        self._choose(t_ns)
        due = self._due
        while due and due[0][0] <= t_ns:
            _, _, action = heapq.heappop(due)
            action(t_ns)
        for sender in self._senders.values():
            sender.poll(t_ns)
        for key in [k for k, s in self._senders.items() if s.done]:
            del self._senders[key]

    @property
    def busy(self) -> bool:
        return bool(self._due or self._senders)

    # ------------------------------------------------------------------ choosing
    def _choose(self, t_ns: int, new_request: bool = False) -> None:
        sched = self.schedule
        cur = sched.new_request(t_ns) if new_request else sched.update(t_ns)
        if cur is not self.current:
            self.current = cur
            self._busy_sent = 0
            self._set_params(cur)

    def _set_params(self, cur: DiagFaultSetting | None) -> None:
        """can-isotp's own parameters for the faults it can commit (FC STmin / BS, padding)."""
        values: dict[str, int | None] = dict(self._defaults)
        if cur is not None and cur.fault.name in _PARAMS:
            values[_PARAMS[cur.fault.name]] = int(cur.value)
        if cur is not None and cur.fault.name == "no_padding":
            values["tx_padding"] = None
        params = self.server.phys.layer.params
        for key, value in values.items():
            params.set(key, value, validate=False)

    # ------------------------------------------------------------------- actions
    def _at(self, t_ns: int, action: Callable[[int], None]) -> None:
        gen = self._generation

        def guarded(now: int) -> None:
            if gen == self._generation:  # a new request ends this one's leftovers
                action(now)

        heapq.heappush(self._due, (t_ns, next(self._seq), guarded))

    def _payload(self, payload: bytes) -> Callable[[int], None]:
        return lambda t: self.server.phys.send(payload)

    def _raw(self, data: bytes) -> Callable[[int], None]:
        """One frame of `data` from the ECU (its response ID): a flow control, a stray SF."""
        def send(t: int) -> None:
            self.node.send(frame(self.cfg.response_id, data, t))
        return send

    def _deliver(self, msg: can.Message) -> Callable[[int], None]:
        return lambda t: self.server.deliver(msg, t)

    def _repeat_pending(self, pending: bytes, t_ns: int) -> None:
        def again(t: int) -> None:
            if self.current is not None and self.current.fault.name == "pending_forever":
                self.server.phys.send(pending)
                self._at(t + round(PENDING_INTERVAL_MS * _MS), again)

        self._at(t_ns + round(PENDING_INTERVAL_MS * _MS), again)

    def _extra_responders(self, cur: DiagFaultSetting, response: bytes, t_ns: int) -> None:
        n = int(cur.value) if cur.fault.name == "functional_multi" else 1
        delay = 0 if cur.fault.name == "functional_multi" else round(cur.value * _MS)
        for k in range(1, n + 1):
            body = response[:-1] + bytes([(response[-1] + k) & 0xFF])  # each ECU its own data
            fc_id, tx_id = self.cfg.request_id + k, self.cfg.response_id + k

            def start(t: int, body: bytes = body, fc_id: int = fc_id, tx_id: int = tx_id) -> None:
                if len(body) <= 7:
                    self.node.send(frame(tx_id, bytes([len(body)]) + body, t))
                else:
                    self._senders[fc_id] = SegmentedSender(body, tx_id, self.node.send, None,
                                                           0, t)

            if delay:
                self._at(t_ns + delay, start)
            else:
                start(t_ns)


def attach_diag_faults(server: UdsServer, settings: Sequence[DiagFaultSetting],
                       source: str = "api") -> EcuDiagFaults | None:
    """Commit `settings` (the ECU-side ones; DoIP faults are the gateway's) on `server`."""
    mine = [s for s in settings if not s.fault.doip]
    if not mine:
        return None
    engine = EcuDiagFaults(server, mine, source)
    server.hook = engine
    if engine.ids:
        server.node.attach(engine)
    return engine
