"""The routing firewall: `[[deny]]` rules drop frames of the listed CAN IDs coming from a bus
before any route sees them, each drop counted under its rule."""

from __future__ import annotations

from collections import Counter

from vecu.gateway.routes import DenyRule


class Firewall:
    def __init__(self, rules: tuple[DenyRule, ...]) -> None:
        self._by_bus: dict[str, list[DenyRule]] = {}
        for rule in rules:
            self._by_bus.setdefault(rule.source, []).append(rule)
        self.dropped: Counter[str] = Counter()  # rule key -> frames dropped

    def blocks(self, bus: str, can_id: int) -> bool:
        """True (and counted) when a rule of `bus` denies `can_id`."""
        for rule in self._by_bus.get(bus, ()):
            if can_id in rule.ids:
                self.dropped[rule.key] += 1
                return True
        return False

    def summary(self) -> dict[str, int]:
        return dict(self.dropped)
