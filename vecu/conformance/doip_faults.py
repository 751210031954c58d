"""The DoIP faults of the catalogue, committed by the gateway's DoIP entity
(vecu.gateway.entity.DoipEntity.faults): a refused routing activation, a diagnostic NACK, a
late or lonely ACK, an alive check request mid-session, the connection closed mid-response, a
generic header NACK, a wrong inverse protocol version (ISO 13400-2:2019 §7). With no fault
active the entity's normal path runs untouched. Each start and end is an FI_Event frame on the
gateway's CAN bus (FI_EvKind 31, FI_EvMessageId the gateway's logical address)."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Sequence
from typing import Any

from doipclient import messages as m

from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.uds.diag_faults.schedule import FaultSchedule
from vecu.uds.diag_faults.setting import DiagFaultSetting


class DoipDiagFaults:
    """Set as `entity.faults`. `alive_responses`: (t_ns, SA) of each alive check response a
    tester sent (the evidence for doip_alive_check)."""

    def __init__(self, settings: Sequence[DiagFaultSetting], logical_address: int,
                 send_frame: Callable[[Any], object] | None = None, source: str = "api") -> None:
        self.address = logical_address
        fi = DbcCodec()["FI_Event"] if send_frame is not None else None
        self.schedule = FaultSchedule([s for s in settings if s.fault.doip], logical_address,
                                      fi, send_frame, source)
        self._due: list[tuple[int, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self.alive_responses: list[tuple[int, int]] = []

    @property
    def current(self) -> DiagFaultSetting | None:
        return self.schedule.current

    # ----------------------------------------------------------------- entity side
    def intercept(self, entity: Any, c: Any, msg: Any, t_ns: int) -> bool:
        if isinstance(msg, m.AliveCheckResponse):
            self.alive_responses.append((t_ns, msg.source_address))
            return False
        if not isinstance(msg, (m.RoutingActivationRequest, m.DiagnosticMessage)):
            return False
        cur = self.schedule.new_request(t_ns)
        if cur is None:
            return False
        name, v = cur.fault.name, int(cur.value)
        if isinstance(msg, m.RoutingActivationRequest):
            if name != "doip_activation_refused":
                return False
            entity.send(c, m.RoutingActivationResponse(msg.source_address, self.address, v))
            return True
        sa, ta = msg.source_address, msg.target_address
        if c.sa is None or sa != c.sa:
            return False  # the entity's own check (NACK 0x02) first
        ack = m.DiagnosticMessagePositiveAcknowledgement(ta, sa, 0x00)
        if name == "doip_diag_nack":
            entity.send(c, m.DiagnosticMessageNegativeAcknowledgement(ta, sa, v))
        elif name == "doip_ack_late":
            self._at(t_ns + round(v * NS_PER_MS), lambda: entity.diagnostic(c, msg))
        elif name == "doip_ack_no_response":
            entity.send(c, ack)
        elif name == "doip_alive_check":
            entity.send(c, m.AliveCheckRequest())
            return False  # then routed as usual
        elif name == "doip_close_mid_response":
            entity.send(c, ack)
            entity.drop(c, "diagnostic fault")
        elif name == "doip_header_nack":
            entity.send(c, m.GenericDoIPNegativeAcknowledge(v))
        else:
            return False  # doip_bad_inverse_version: outgoing()
        return True

    def outgoing(self, c: Any, data: bytes) -> bytes:
        cur = self.current
        if cur is None or cur.fault.name != "doip_bad_inverse_version":
            return data
        return data[:1] + bytes([data[1] ^ 0x01]) + data[2:]  # inverse != ~version

    def tick(self, entity: Any, t_ns: int) -> None:
        self.schedule.update(t_ns)
        due = self._due
        while due and due[0][0] <= t_ns:
            heapq.heappop(due)[2]()

    # ----------------------------------------------------------------------- state
    def _at(self, t_ns: int, action: Callable[[], None]) -> None:
        heapq.heappush(self._due, (t_ns, next(self._seq), action))
