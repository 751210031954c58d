"""What every bus node shares: its python-can bus and counted, never-raising sends."""

from __future__ import annotations

import logging
from collections.abc import Callable

import can

MAX_LOGGED_SEND_ERRORS = 20


class BusNode:
    """Base of the plant and ECU nodes: send() counts frames and failures instead of raising."""

    def __init__(self, bus: can.BusABC, name: str) -> None:
        self.bus = bus
        self.node_name = name
        self.frames_sent = 0
        self.send_errors = 0
        self.tap: Callable[[can.Message], None] | None = None  # sees every frame sent (replay --out)
        self._log = logging.getLogger(f"vecu.{name}")

    def _send(self, msg: can.Message) -> bool:
        try:
            self.bus.send(msg)
            self.frames_sent += 1
            if self.tap is not None:
                self.tap(msg)
            return True
        except can.CanError as exc:
            self.send_errors += 1
            if self.send_errors <= MAX_LOGGED_SEND_ERRORS:
                self._log.warning("%s: send failed for 0x%X: %s", self.node_name,
                                  msg.arbitration_id, exc)
            return False
