"""One TCP_DATA connection of the DoIP entity: its socket, where the stream reader stands
(header bytes so far, the message being received, bytes of a discarded one still to skip), the
routing it holds and what waits to be sent."""

from __future__ import annotations

import socket
from typing import Any

from vecu.gateway import doip


class Connection:
    """State of one tester's TCP connection (the entity's socket table holds these)."""

    def __init__(self, serial: int, sock: socket.socket, peer: Any, t_ns: int,
                 version: int) -> None:
        self.serial = serial
        self.sock = sock
        self.peer = peer
        self.opened_ns = t_ns
        self.last_rx_ns = t_ns
        self.version = version        # of the last message received: answers use it
        self.hbuf = bytearray()       # header bytes so far (< 8)
        self.header: doip.Header | None = None  # of the message being received
        self.payload = bytearray()    # its payload so far (never more than header.length)
        self.reserved = 0             # payload memory reserved for it (the entity's budget)
        self.skip = 0                 # bytes of a NACKed message still to drop
        self.sa: int | None = None    # tester logical address with routing active here
        self.activation_type: int | None = None
        self.out = bytearray()        # queued output
        self.closed = False
