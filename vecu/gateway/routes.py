"""The records of routing between CAN buses (routes_config reads them from the gateway config
file, routes_check checks them across routes, vecu.gateway.routing runs them)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vecu.codec import DbcCodec
from vecu.e2e import E2EProtection


@dataclass(frozen=True)
class BusSpec:
    """One bus the gateway joins: its python-can arguments and its databases' codec."""

    name: str
    args: tuple[tuple[str, Any], ...]
    codec: DbcCodec


@dataclass(frozen=True)
class FrameRoute:
    """Frames matched on `source` (an (ID, extended) set, or id/mask) copied to `target`."""

    key: str                                    # "routes[i]": its place in the file
    source: str
    target: str
    ids: frozenset[tuple[int, bool]] = frozenset()
    id_mask: tuple[int, int] | None = None      # (id, mask): arbitration_id & mask == id
    new_id: int | None = None
    min_interval_ns: int = 0
    delay_ns: int = 0
    e2e_check: bool = False   # check-and-forward: frames failing their E2E check dropped

    @property
    def mask_extended(self) -> bool:
        """An id/mask route matches 29-bit frames when its id or mask is above 0x7FF."""
        return self.id_mask is not None and max(self.id_mask) > 0x7FF

    def matches(self, can_id: int, extended: bool) -> bool:
        """A frame of this ID and 11/29-bit format is one the route copies."""
        if (can_id, extended) in self.ids:
            return True
        return (self.id_mask is not None and extended == self.mask_extended
                and can_id & self.id_mask[1] == self.id_mask[0])


@dataclass(frozen=True)
class SignalMap:
    """One target signal and where it comes from (unit converted: target = x * factor + offset)."""

    target: str
    message: str
    signal: str
    factor: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class SignalRoute:
    """Signals of source messages on `source` repacked into message `message` on `target`."""

    key: str
    source: str
    target: str
    message: str
    signals: tuple[SignalMap, ...]
    send: str = "cyclic"
    cycle_ns: int = 0                   # the target's database cycle time (cyclic, both)
    timeout_ns: int = 0                 # 0: none
    min_interval_ns: int = 0
    delay_ns: int = 0
    e2e: E2EProtection | None = None
    mux: tuple[tuple[str, int], ...] = ()   # multiplexer selector values the targets need


@dataclass(frozen=True)
class DenyRule:
    key: str
    source: str
    ids: frozenset[int]


@dataclass(frozen=True)
class RoutingConfig:
    """The buses (the first named: the one the plant and ECU join in `vecu run`) and routes."""

    buses: tuple[BusSpec, ...] = ()
    frame_routes: tuple[FrameRoute, ...] = ()
    signal_routes: tuple[SignalRoute, ...] = ()
    deny: tuple[DenyRule, ...] = ()

    def bus(self, name: str) -> BusSpec:
        return next(b for b in self.buses if b.name == name)
