"""The gateway's own diagnostic server (ISO 14229-1) at its logical address: TesterPresent,
DiagnosticSessionControl (default / extended) and ReadDataByIdentifier for its VIN, routing table
and per-route counters (docs/gateway.md "The gateway's own DIDs"). Service IDs and response codes
are udsoncan's; answers are built in the request's tick, with no CAN traffic.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

from udsoncan import Response, services

from vecu.clock import NS_PER_MS
from vecu.gateway.config import ADDRESSING, GatewayConfig
from vecu.uds.server import FUNCTIONAL_SILENT

log = logging.getLogger(__name__)
C = Response.Code
Session = services.DiagnosticSessionControl.Session
SESSIONS = (Session.defaultSession, Session.extendedDiagnosticSession)
P2_MS, P2_STAR_MS, S3_MS = 50, 5000, 5000  # the gateway answers in the request's tick

DID_VIN = 0xF190            # ISO 14229-1 C.1: VINDataIdentifier
DID_SESSION = 0xF186        # ISO 14229-1 C.1: ActiveDiagnosticSessionDataIdentifier
DID_ROUTES = 0xFD00         # systemSupplierSpecific (0xFD00-0xFEFF): the routing table
DID_ROUTE_COUNTERS = 0xFD01  # the routes' counters
ADDRESSING_CODES = {name: i for i, name in enumerate(ADDRESSING)}
NO_BYTE = 0xFF
# one row of DID_ROUTE_COUNTERS: logical address, then these counters (4 bytes each)
COUNTER_FIELDS = ("requests", "responses", "pending_relayed", "timeouts", "transport_errors",
                  "nacks")
Counters = Callable[[], Sequence[tuple[int, Sequence[int]]]]  # (logical address, COUNTER_FIELDS)


def _u32(n: int) -> bytes:
    return min(n, 0xFFFFFFFF).to_bytes(4, "big")


def routing_table(cfg: GatewayConfig) -> bytes:
    """DID 0xFD00: row count, then per route (the ECUs, then the functional row) logical
    address (2), addressing code (1, ADDRESSING's order), request CAN ID (4), response CAN ID
    (4, 0xFFFFFFFF for the functional row), address byte N_TA (1, 0xFF when not used)."""
    rows = [r.logical_address.to_bytes(2, "big") + bytes([ADDRESSING_CODES[r.addressing]])
            + _u32(r.request_id) + _u32(r.response_id)
            + bytes([r.target_address if r.target_address is not None
                     and r.addressing != "normal_11bit" else NO_BYTE])
            for r in cfg.ecus]
    rows.append(cfg.functional_address.to_bytes(2, "big")
                + bytes([ADDRESSING_CODES[cfg.functional_addressing]])
                + _u32(cfg.functional_id) + _u32(0xFFFFFFFF) + bytes([NO_BYTE]))
    return bytes([len(rows)]) + b"".join(rows)


class GatewayUds:
    """Answers UDS requests addressed to the gateway's logical address."""

    def __init__(self, config: GatewayConfig, counters: Counters) -> None:
        self.cfg = config
        self.session = Session.defaultSession
        self._s3_deadline = 0
        self._routes = routing_table(config)
        self.dids: dict[int, Callable[[], bytes]] = {
            DID_VIN: lambda: config.vin.encode("ascii"),
            DID_SESSION: lambda: bytes([self.session]),
            DID_ROUTES: lambda: self._routes,
            DID_ROUTE_COUNTERS: lambda: self._counter_rows(counters()),
        }
        # service ID -> (handler, has a sub-function), both from udsoncan's service classes
        self._services: dict[int, tuple[Callable[[bytes, int], bytes | int], bool]] = {
            service.request_id(): (handler, service.use_subfunction())
            for service, handler in ((services.TesterPresent, self._tester_present),
                                     (services.DiagnosticSessionControl, self._session_control),
                                     (services.ReadDataByIdentifier, self._read_dids))}

    @staticmethod
    def _counter_rows(rows: Sequence[tuple[int, Sequence[int]]]) -> bytes:
        return bytes([len(rows)]) + b"".join(
            la.to_bytes(2, "big") + b"".join(_u32(n) for n in values) for la, values in rows)

    def handle(self, payload: bytes, functional: bool, t_ns: int) -> bytes | None:
        """The response to one request (None: none, ISO 14229-1 suppressPosRspMsgIndicationBit
        or a functional request's suppressed negative response)."""
        if self.session != Session.defaultSession and t_ns >= self._s3_deadline:
            self.session = Session.defaultSession  # S3 expired since the last request
        self._s3_deadline = t_ns + S3_MS * NS_PER_MS
        if not payload:
            return None
        sid = payload[0]
        service = self._services.get(sid)
        result = C.ServiceNotSupported if service is None else service[0](payload, t_ns)
        if isinstance(result, int):
            if functional and result in FUNCTIONAL_SILENT:
                return None
            return bytes([0x7F, sid, result])
        if service is not None and service[1] and payload[1] & 0x80:
            return None  # suppressPosRspMsgIndicationBit
        return bytes([sid + 0x40]) + result

    def _tester_present(self, p: bytes, t_ns: int) -> bytes | int:
        if len(p) != 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        if p[1] & 0x7F != 0:
            return C.SubFunctionNotSupported
        return b"\x00"

    def _session_control(self, p: bytes, t_ns: int) -> bytes | int:
        if len(p) != 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        sub = p[1] & 0x7F
        if sub not in SESSIONS:  # no programming or safety session: the gateway has no flash
            return C.SubFunctionNotSupported
        self.session = sub
        return bytes([sub]) + P2_MS.to_bytes(2, "big") + (P2_STAR_MS // 10).to_bytes(2, "big")

    def _read_dids(self, p: bytes, t_ns: int) -> bytes | int:
        n = len(p) - 1
        if n == 0 or n % 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        out = b""
        for i in range(1, len(p), 2):
            value = self.dids.get(int.from_bytes(p[i:i + 2], "big"))
            if value is not None:
                out += p[i:i + 2] + value()
        return out or C.RequestOutOfRange
