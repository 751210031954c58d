"""What the DoIP entity (vecu.gateway.entity) needs from the parts around it: the router its
diagnostic messages go to, the identity it announces, and a hook that commits diagnostic faults
on purpose (vecu.conformance.doip_faults)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol


class Router(Protocol):
    def submit(self, source: int, target: int, uds: bytes,
               reply: Callable[[int, bytes], None]) -> int | None: ...

    def cancel(self, source: int) -> None: ...


class Identity(Protocol):
    """What the entity announces (GatewayConfig)."""

    @property
    def vin(self) -> str: ...
    @property
    def eid(self) -> bytes: ...
    @property
    def gid(self) -> bytes: ...
    @property
    def logical_address(self) -> int: ...
    @property
    def tester_addresses(self) -> tuple[int, int]: ...


class FaultHook(Protocol):
    """Diagnostic faults at the entity: intercept() takes a tester's message instead of the
    entity (True: taken), outgoing() may alter the bytes of each message to a tester, tick()
    runs what it scheduled."""

    def intercept(self, entity: Any, c: Any, msg: Any, t_ns: int) -> bool: ...
    def outgoing(self, c: Any, data: bytes) -> bytes: ...
    def tick(self, entity: Any, t_ns: int) -> None: ...
