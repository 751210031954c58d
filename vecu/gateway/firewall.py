"""The routing firewall: `[[deny]]` rules drop frames of the listed CAN IDs coming from a bus
before any route sees them, each drop counted under its rule."""

from __future__ import annotations

from collections import Counter

from vecu.gateway.routes import DenyRule


class Firewall:
    def __init__(self, rules: tuple[DenyRule, ...]) -> None:
        self._denied: dict[tuple[str, int], str] = {}  # (bus, CAN ID) -> the first rule's key
        for rule in rules:
            for can_id in rule.ids:
                self._denied.setdefault((rule.source, can_id), rule.key)
        self.dropped: Counter[str] = Counter()  # rule key -> frames dropped

    def blocks(self, bus: str, can_id: int) -> bool:
        """True (and counted) when a rule of `bus` denies `can_id`."""
        key = self._denied.get((bus, can_id))
        if key is None:
            return False
        self.dropped[key] += 1
        return True

    def summary(self) -> dict[str, int]:
        return dict(self.dropped)
