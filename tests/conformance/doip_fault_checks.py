"""Inside a private network namespace: the gateway's DoIP entity on 127.0.0.1 with one DoIP
fault at a time (vecu.conformance.doip_faults), a stand-in router that answers each request
one step later, and a raw-socket tester (doipclient's Parser reads the wire) that activates
routing, sends ReadDataByIdentifier 0xF190 and records every message that comes back with its
time; it answers alive check requests as ISO 13400-2 asks. Prints one JSON line.
Usage: python tests/conformance/doip_fault_checks.py"""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from doipclient import messages as m
from doipclient.client import Parser

from vecu.bus import BusNode, open_bus
from vecu.clock import WallClock
from vecu.conformance.doip_faults import DoipDiagFaults
from vecu.gateway.config import default_config
from vecu.gateway.entity import DoipEntity
from vecu.gateway.settings import settings_of
from vecu.uds.diag_faults.setting import parse_setting

TESTER, ECU = 0x0E00, 0x0010
ANSWER = b"\x62\xf1\x90" + b"1VECU00SIM0000001"
SPECS = ["doip_activation_refused=4", "doip_diag_nack=6", "doip_ack_late=2500",
         "doip_ack_no_response", "doip_alive_check", "doip_close_mid_response",
         "doip_header_nack=2", "doip_bad_inverse_version"]


class LaterRouter:
    def __init__(self) -> None:
        self.pending: list[Any] = []

    def submit(self, source: int, target: int, uds: bytes, reply: Any) -> int | None:
        self.pending.append(reply)
        return None

    def cancel(self, source: int) -> None:
        pass

    def step(self) -> None:
        while self.pending:
            self.pending.pop(0)(ECU, ANSWER)


def frame(ptype: int, payload: bytes) -> bytes:
    return struct.pack("!BBHL", 2, 0xFD, ptype, len(payload)) + payload


def observe(spec: str, port: int) -> dict[str, Any]:
    cfg = default_config()
    node = BusNode(open_bus("virtual", f"doip-fault-{port}"), "gateway")
    fi: list[bytes] = []
    router = LaterRouter()
    e = DoipEntity(cfg, settings_of(cfg), router, node, 60.0, "127.0.0.1", port)
    e.faults = faults = DoipDiagFaults([parse_setting(spec)], cfg.logical_address,
                                       lambda f: fi.append(bytes(f.data)))
    e.open()
    clock = WallClock(spin_ns=0)
    clock.start()
    stop = threading.Event()

    def loop() -> None:
        t = 0
        while not stop.is_set():
            t += 1_000_000
            clock.wait_until(t)
            e.step(t)
            router.step()

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    s = socket.create_connection(("127.0.0.1", port), timeout=2.0)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    parser, raw = Parser(), bytearray()
    t0 = time.monotonic()
    seen: list[Any] = []

    def read_all(quiet_s: float) -> None:
        s.settimeout(0.05)
        last = time.monotonic()
        while time.monotonic() - last < quiet_s:
            try:
                data = s.recv(4096)
            except TimeoutError:
                continue
            except ConnectionResetError:
                data = b""
            if not data:
                seen.append([round((time.monotonic() - t0) * 1000), "closed"])
                return
            raw.extend(data)
            last = time.monotonic()
            got = parser.read_message(data)
            while got is not None:
                seen.append([round((time.monotonic() - t0) * 1000), type(got).__name__,
                             {k: (int(v) if isinstance(v, int) else None if v is None else bytes(v).hex())
                              for k, v in ((f, getattr(got, f)) for f in got._fields)}])
                if isinstance(got, m.AliveCheckRequest):
                    s.sendall(frame(0x0008, m.AliveCheckResponse(TESTER).pack()))
                got = parser.read_message(b"")

    s.sendall(frame(0x0005, m.RoutingActivationRequest(TESTER, 0).pack()))
    read_all(0.3)
    sent_ms = round((time.monotonic() - t0) * 1000)
    try:
        s.sendall(frame(0x8001, struct.pack("!HH", TESTER, ECU) + b"\x22\xf1\x90"))
        read_all(2.8 if spec.startswith("doip_ack_late") else 0.8)
    except OSError:
        seen.append([sent_ms, "send failed"])
    stop.set()
    thread.join(2.0)
    s.close()
    e.close()
    node.bus.shutdown()
    return {"seen": seen, "sent_ms": sent_ms, "raw": raw.hex(), "fi_event": [f.hex() for f in fi],
            "alive_responses": [sa for _, sa in faults.alive_responses]}


def main() -> None:
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    out = {spec.split("=")[0]: observe(spec, 13400 + k) for k, spec in enumerate(SPECS)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
