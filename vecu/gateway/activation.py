"""Routing activation (ISO 13400-2:2019 §7.4.3, Figures 7 / 8 and Table 49): the source address
check, the activation type, the TCP_DATA socket handler with its alive checks, authentication
and confirmation, and the response code each outcome gets.

Codes and what triggers them here (the non-default ones by the `[doip]` config keys):
  0x00 SA outside the tester range (config tester_addresses)            socket closed
  0x01 every socket of the table active and each answers an alive check socket closed
  0x02 this socket already active for another SA                        socket closed
  0x03 the SA active on another socket that answers an alive check      socket closed
  0x04 an activation type in `authentication_types` (vecu has no authentication to offer)
  0x05 an activation type in `confirmation_types` (nobody in the vehicle confirms)
  0x06 an activation type not in `activation_types`                     socket closed
  0x10 routing activated
A socket that does not answer its alive check within T_TCP_Alive_Check is closed and its place
goes to the new tester.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Protocol

from doipclient import messages as m

from vecu.gateway.connection import Connection
from vecu.gateway.doip import ActivationCode
from vecu.gateway.settings import DoipSettings


class Entity(Protocol):
    """What the handler uses of the DoIP entity (vecu.gateway.entity.DoipEntity)."""

    s: DoipSettings
    ident: Any
    conns: dict[int, Connection]
    count: dict[str, Counter[str]]

    def bad(self, kind: str, text: str) -> None: ...
    def send(self, c: Connection, msg: m.DoIPMessage) -> None: ...
    def drop(self, c: Connection, reason: str) -> None: ...

CLOSES = frozenset({ActivationCode.DeniedUnknownSourceAddress,
                    ActivationCode.DeniedAllSocketsRegisteredActive,
                    ActivationCode.DeniedSADoesNotMatch, ActivationCode.DeniedSARegistered,
                    ActivationCode.DeniedUnsupportedActivationType})


@dataclass
class Pending:
    """A request waiting for the alive checks of the sockets it would displace."""

    conn: Connection
    req: m.RoutingActivationRequest
    code_if_alive: int            # 0x01 (table full) or 0x03 (SA active elsewhere)
    deadline_ns: int
    targets: set[int]             # serials of the sockets asked
    answered: set[int] = field(default_factory=set)


class ActivationHandler:
    def __init__(self, entity: Entity) -> None:
        self.e = entity
        self.pending: list[Pending] = []

    def request(self, c: Connection, req: m.RoutingActivationRequest, t_ns: int) -> None:
        e, s = self.e, self.e.s
        sa, kind = req.source_address, req._activation_type
        lo, hi = e.ident.tester_addresses
        if self.pending_for(c):
            e.bad("activation_while_pending", f"{c.peer}: a second routing activation while "
                  "the first waits for alive checks: ignored")
            return
        if not lo <= sa <= hi:
            self._respond(c, sa, ActivationCode.DeniedUnknownSourceAddress,
                          f"SA 0x{sa:04X} outside 0x{lo:04X}-0x{hi:04X}")
            return
        if kind not in s.activation_types:
            self._respond(c, sa, ActivationCode.DeniedUnsupportedActivationType,
                          f"activation type 0x{kind:02X}")
            return
        if c.sa is not None and c.sa != sa:
            self._respond(c, sa, ActivationCode.DeniedSADoesNotMatch,
                          f"SA 0x{sa:04X} on a socket active for 0x{c.sa:04X}")
            return
        if c.sa is None:
            other = [o for o in e.conns.values() if o.sa == sa and o is not c]
            if other:
                self._check_alive(c, req, ActivationCode.DeniedSARegistered, other, t_ns)
                return
            active = [o for o in e.conns.values() if o.sa is not None]
            if len(active) >= s.max_sockets:
                self._check_alive(c, req, ActivationCode.DeniedAllSocketsRegisteredActive,
                                  active, t_ns)
                return
        self._finish(c, req)

    def _finish(self, c: Connection, req: m.RoutingActivationRequest) -> None:
        s = self.e.s
        sa, kind = req.source_address, req._activation_type
        if kind in s.authentication:
            self._respond(c, sa, ActivationCode.DeniedMissingAuthentication,
                          f"activation type 0x{kind:02X} without its authentication")
            return
        if kind in s.confirmation:
            self._respond(c, sa, ActivationCode.DeniedRejectedConfirmation,
                          f"activation type 0x{kind:02X}: confirmation rejected")
            return
        c.sa, c.activation_type = sa, kind
        self._respond(c, sa, ActivationCode.Success, "")

    def _respond(self, c: Connection, sa: int, code: int, why: str) -> None:
        e = self.e
        e.count["activations"][f"0x{code:02X}"] += 1
        if code != ActivationCode.Success:
            e.bad(f"activation_denied_0x{code:02X}",
                  f"{c.peer}: routing activation denied 0x{code:02X}: {why}")
        e.send(c, m.RoutingActivationResponse(sa, e.ident.logical_address, code))
        if code in CLOSES:
            e.drop(c, f"routing activation denied 0x{code:02X}")

    def _check_alive(self, c: Connection, req: m.RoutingActivationRequest, code: int,
                     targets: list[Connection], t_ns: int) -> None:
        e = self.e
        for o in targets:
            e.count["alive_checks"]["sent"] += 1
            e.send(o, m.AliveCheckRequest())
        self.pending.append(Pending(c, req, code, t_ns + e.s.ns(e.s.alive_check_s),
                                    {o.serial for o in targets}))

    def alive(self, c: Connection, sa: int) -> None:
        asked = [p for p in self.pending if c.serial in p.targets]
        self.e.count["alive_checks"]["answered" if asked else "unsolicited"] += 1
        for p in asked:
            p.answered.add(c.serial)

    def tick(self, t_ns: int) -> None:
        if not self.pending:
            return
        e = self.e
        for p in list(self.pending):
            if p not in self.pending:  # its requester closed meanwhile (forget)
                continue
            gone = {s for s in p.targets if s not in e.conns}
            if p.answered | gone != p.targets and t_ns < p.deadline_ns:
                continue
            self.pending.remove(p)
            for serial in p.targets - p.answered - gone:
                e.count["alive_checks"]["timed_out"] += 1
                o = e.conns.get(serial)
                if o is not None:
                    e.drop(o, "alive check timeout")
            if p.conn.closed:
                continue
            if p.answered - gone == p.targets:  # every socket asked is alive: no place
                self._respond(p.conn, p.req.source_address, p.code_if_alive,
                              "the sockets asked answered their alive checks")
            else:
                self._finish(p.conn, p.req)

    def pending_for(self, c: Connection) -> bool:
        return any(p.conn is c for p in self.pending)

    def forget(self, c: Connection) -> None:
        self.pending = [p for p in self.pending if p.conn is not c]
