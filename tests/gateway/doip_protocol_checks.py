"""Inside a private network namespace: `vecu gateway` alone (an empty virtual CAN bus) on
127.0.0.1, and raw TCP / UDP sockets that provoke every DoIP response code: the generic NACKs
(ISO 13400-2:2019 Table 19), routing activation codes (Table 49), diagnostic message NACK 0x02
and 0x03, the inactivity timers, the socket table and its alive checks; then a bounded fuzz of
headers and payloads. doipclient's Parser reads every answer (the oracle of the wire format).
Prints one JSON line of observations; tests/gateway/test_doip_protocol.py asserts on them.
Usage: python tests/gateway/doip_protocol_checks.py OUTDIR"""

from __future__ import annotations

import contextlib
import json
import random
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from doipclient import DoIPClient
from doipclient import messages as m
from doipclient.client import Parser

from vecu.live.scenario import stop_all

HOST, PORT = "127.0.0.1", 13400
CONFIG = """
[doip]
initial_inactivity_s = 0.6
general_inactivity_s = 1.0
activation_types = [0x00, 0x01, 0xE0, 0xE1]
authentication_types = [0xE0]
confirmation_types = [0xE1]
"""
FUZZ_SECONDS = 3.0
PARSERS: dict[int, Parser] = {}


def header(ptype: int, length: int, version: int = 2, inverse: int | None = None) -> bytes:
    return struct.pack("!BBHL", version, version ^ 0xFF if inverse is None else inverse, ptype,
                       length)


def msg(ptype: int, payload: bytes = b"", **kw: Any) -> bytes:
    return header(ptype, len(payload), **kw) + payload


def connect() -> socket.socket:
    s = socket.create_connection((HOST, PORT), timeout=2.0)
    PARSERS.pop(id(s), None)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def read(s: socket.socket, timeout: float = 2.0) -> Any:
    """The next DoIP message (doipclient's class), "closed" at EOF, None on a timeout."""
    s.settimeout(timeout)
    parser = PARSERS.setdefault(id(s), Parser())  # one per connection (TCP is a stream)
    got = parser.read_message(b"")
    while got is None:
        try:
            data = s.recv(4096)
        except TimeoutError:
            return None
        except ConnectionResetError:
            return "closed"
        if not data:
            return "closed"
        got = parser.read_message(data)
    return got


def name(x: Any) -> Any:
    """An observation as JSON: [class name, its fields] or a string."""
    if x is None or isinstance(x, str):
        return x
    fields = {f: getattr(x, f) for f in x._fields}
    return [type(x).__name__, {k: (int(v) if isinstance(v, int) else str(v))
                               for k, v in fields.items()}]


def activate(s: socket.socket, sa: int, kind: int = 0, oem: int | None = None) -> Any:
    s.sendall(msg(0x0005, m.RoutingActivationRequest(sa, kind, vm_specific=oem).pack()))
    return read(s)


def code_and_closed(s: socket.socket, first: Any) -> dict:
    nxt = read(s, timeout=0.3) if not isinstance(first, str) else first
    s.close()
    return {"answer": name(first), "then": name(nxt)}


def udp(data: bytes) -> Any:
    u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    u.settimeout(1.0)
    u.sendto(data, (HOST, PORT))
    try:
        reply, _ = u.recvfrom(4096)
    except TimeoutError:
        return None
    finally:
        u.close()
    p = Parser()
    return name(p.read_message(reply))


def generic(out: dict) -> None:
    o = out["generic"] = {}
    s = connect()  # 0x00: wrong inverse version -> NACK, closed
    s.sendall(header(0x0005, 7, inverse=0x00) + bytes(7))
    o["pattern"] = code_and_closed(s, read(s))
    s = connect()  # 0x00: version 0xFF on TCP (only identification requests may use it)
    s.sendall(header(0x0005, 7, version=0xFF) + bytes(7))
    o["default_version_on_tcp"] = code_and_closed(s, read(s))
    s = connect()  # 0x01: unknown payload type, payload skipped, socket kept
    s.sendall(msg(0x1234, b"abc"))
    o["unknown_type"] = name(read(s))
    o["unknown_type_then_activation"] = name(activate(s, 0x0E00))
    s.close()
    s = connect()  # 0x02: 2**32 - 1 bytes announced: never allocated, skipped, socket kept
    s.sendall(header(0x8001, 0xFFFFFFFF) + b"\x0e\x00\x00\x10")
    o["too_large"] = name(read(s))
    s.close()
    s = connect()  # 0x04: a routing activation of 3 bytes -> NACK, closed
    s.sendall(msg(0x0005, b"\x0e\x00\x00"))
    o["bad_length"] = code_and_closed(s, read(s))
    # 0x03: four sockets each receiving a 4095-byte message hold the memory; the fifth NACKed
    holders = [connect() for _ in range(4)]
    for h in holders:
        h.sendall(header(0x8001, 4095))
    time.sleep(0.05)
    s = connect()
    s.sendall(header(0x8001, 4095))
    o["out_of_memory"] = name(read(s))
    for h in [*holders, s]:
        h.close()
    o["udp"] = {
        "pattern": udp(header(0x0001, 0, inverse=0x12)),
        "unknown_type": udp(msg(0x0005, bytes(7))),
        "too_large": udp(header(0x0001, 0x10000)),
        "bad_length": udp(msg(0x0002, b"\x01\x02")),
        "truncated": udp(b"\x02\xfd\x00"),
        "version_ff_identification": udp(msg(0x0001, version=0xFF)),
        "version_ff_diagnostic": udp(msg(0x8001, b"\x0e\x00\x00\x10\x3e", version=0xFF)),
        "by_vin_other": udp(msg(0x0003, b"WRONGVIN000000000")),
        "by_eid": udp(msg(0x0002, bytes.fromhex("020000001000"))),
        "entity_status": udp(msg(0x4001)),
        "power_mode": udp(msg(0x4003)),
    }


def versions(out: dict) -> None:
    """Protocol versions 2 (2012) and 3 (2019): an answer carries the request's version; one
    to version 0xFF (identification only) the entity's own (2)."""
    o = out["versions"] = {}
    for v in (2, 3, 0xFF):
        u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        u.settimeout(1.0)
        u.sendto(msg(0x0001, version=v), (HOST, PORT))
        o[f"udp_{v}"] = list(u.recvfrom(64)[0][:2])
        u.close()
    s = connect()
    s.sendall(msg(0x0005, m.RoutingActivationRequest(0x0E00, 0).pack(), version=3))
    s.settimeout(1.0)
    o["tcp_3"] = list(s.recv(2))
    s.close()


def answer_alive_checks(socks: list[socket.socket], sas: list[int]) -> int:
    n = 0
    for s, sa in zip(socks, sas):
        got = read(s, timeout=1.0)
        if isinstance(got, m.AliveCheckRequest):
            s.sendall(msg(0x0008, struct.pack("!H", sa)))
            n += 1
    return n


def activation(out: dict) -> None:
    o = out["activation"] = {}
    s = connect()
    o["0x00"] = code_and_closed(s, activate(s, 0x0001))
    s = connect()
    o["0x06"] = code_and_closed(s, activate(s, 0x0E00, kind=0x42))
    s = connect()
    o["0x04"] = code_and_closed(s, activate(s, 0x0E00, kind=0xE0))
    s = connect()
    o["0x05"] = code_and_closed(s, activate(s, 0x0E00, kind=0xE1))
    s = connect()
    o["0x10"] = name(activate(s, 0x0E00))
    o["0x10_again_same_sa"] = name(activate(s, 0x0E00))
    o["0x02"] = code_and_closed(s, activate(s, 0x0E01))
    # 0x03: SA active on another socket that answers its alive check
    a = connect()
    activate(a, 0x0E05)
    b = connect()
    b.sendall(msg(0x0005, m.RoutingActivationRequest(0x0E05, 0).pack()))
    o["0x03_alive_answered"] = answer_alive_checks([a], [0x0E05])
    o["0x03"] = code_and_closed(b, read(b))
    # ... and one that does not: it is closed, the new socket gets the SA
    b = connect()
    b.sendall(msg(0x0005, m.RoutingActivationRequest(0x0E05, 0).pack()))
    o["0x03_silent_then"] = name(read(b))
    o["0x03_silent_old_socket"] = name(read(a, timeout=0.2)), name(read(a, timeout=1.0))
    a.close()
    b.close()
    # 0x01: the table full (4 active), each answering -> the fifth denied
    table = [connect() for _ in range(4)]
    sas = [0x0E10 + k for k in range(4)]
    o["table"] = [name(activate(t, sa)) for t, sa in zip(table, sas)]
    e = connect()
    e.sendall(msg(0x0005, m.RoutingActivationRequest(0x0E20, 0).pack()))
    o["0x01_alive_answered"] = answer_alive_checks(table, sas)
    o["0x01"] = code_and_closed(e, read(e))
    # a sixth TCP connection while five are open: closed at once
    e = connect()
    extra = connect()
    o["extra_connection"] = name(read(extra, timeout=1.0))
    extra.close()
    # ... and with nobody answering, the fifth gets a place
    e.sendall(msg(0x0005, m.RoutingActivationRequest(0x0E20, 0).pack()))
    o["0x01_silent_then"] = name(read(e, timeout=2.0))
    for t in [*table, e]:
        t.close()


def diagnostic(out: dict) -> None:
    o = out["diagnostic"] = {}
    s = connect()  # before routing activation: NACK 0x02, closed
    s.sendall(msg(0x8001, m.DiagnosticMessage(0x0E00, 0x1000, b"\x3e\x00").pack()))
    o["before_activation"] = code_and_closed(s, read(s))
    s = connect()
    activate(s, 0x0E00)
    s.sendall(msg(0x8001, m.DiagnosticMessage(0x0E00, 0x0777, b"\x3e\x00").pack()))
    o["unknown_target"] = name(read(s))
    s.sendall(msg(0x8001, m.DiagnosticMessage(0x0E00, 0x1000, b"\x22\xf1\x90").pack()))
    o["own_address_ack"] = name(read(s))
    o["own_address_answer"] = name(read(s))
    s.sendall(msg(0x8001, m.DiagnosticMessage(0x0E07, 0x1000, b"\x3e\x00").pack()))
    o["foreign_sa"] = code_and_closed(s, read(s))


def flood(out: dict, n: int = 2000) -> None:
    """Thousands of requests in one burst from one tester: each acked or NACKed (0x05 when the
    gateway's own answer queue is full), none lost, and the gateway answers afterwards."""
    s = connect()
    activate(s, 0x0E00)
    one = msg(0x8001, m.DiagnosticMessage(0x0E00, 0x1000, b"\x3e\x00").pack())
    s.sendall(one * n)
    seen: dict[str, int] = {}
    acks = nacks = answers = 0
    while acks + nacks < n or answers < acks:  # T_TCP_General_Inactivity is 1 s here
        got = read(s, timeout=0.5)
        if got is None or isinstance(got, str):
            break
        acks += isinstance(got, m.DiagnosticMessagePositiveAcknowledgement)
        nacks += isinstance(got, m.DiagnosticMessageNegativeAcknowledgement)
        answers += isinstance(got, m.DiagnosticMessage)
        key = type(got).__name__
        if isinstance(got, m.DiagnosticMessageNegativeAcknowledgement):
            key += f"_0x{got.nack_code:02X}"
        seen[key] = seen.get(key, 0) + 1
    s.sendall(one)
    after = [name(read(s)), name(read(s))]
    s.close()
    out["flood"] = {"sent": n, "seen": seen, "after": after}


def timers(out: dict) -> None:
    o = out["timers"] = {}
    t0 = time.monotonic()
    s = connect()
    s.sendall(b"\x02\xfd\x00")  # half a header, then nothing
    o["half_header"] = name(read(s, timeout=3.0))
    o["half_header_closed_after_s"] = round(time.monotonic() - t0, 2)
    s.close()
    s = connect()
    activate(s, 0x0E00)
    t0 = time.monotonic()
    o["general"] = name(read(s, timeout=3.0))
    o["general_closed_after_s"] = round(time.monotonic() - t0, 2)
    s.close()


def fuzz(out: dict, seed: int = 40) -> None:
    """Random and mutated headers / payloads over TCP and UDP for FUZZ_SECONDS; afterwards the
    gateway must still discover, activate and answer."""
    rng = random.Random(seed)
    valid = [msg(0x0005, m.RoutingActivationRequest(0x0E00, 0).pack()),
             msg(0x8001, m.DiagnosticMessage(0x0E00, 0x1000, b"\x22\xf1\x90").pack()),
             msg(0x0007), msg(0x0008, b"\x0e\x00"), msg(0x0001), msg(0x4001)]
    sent = 0
    end = time.monotonic() + FUZZ_SECONDS
    while time.monotonic() < end:
        base = bytearray(rng.choice(valid))
        kind = rng.randrange(5)
        if kind == 0:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        elif kind == 1:  # flip bytes of the header
            for _ in range(rng.randrange(1, 4)):
                base[rng.randrange(8)] = rng.randrange(256)
            data = bytes(base)
        elif kind == 2:  # a random length
            base[4:8] = struct.pack("!L", rng.choice([0, 1, 3, 6, 7, 11, 4095, 4096, 65535,
                                                      0xFFFFFFFF, rng.randrange(1 << 32)]))
            data = bytes(base)
        elif kind == 3:  # truncated
            data = bytes(base[:rng.randrange(1, len(base))])
        else:
            data = bytes(base) * rng.randrange(1, 4)
        sent += 1
        if rng.random() < 0.3:
            u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            u.sendto(data, (HOST, PORT))
            u.close()
            continue
        try:
            s = connect()
            s.sendall(data)
            s.settimeout(0.05)
            with contextlib.suppress(OSError):  # a timeout too
                s.recv(4096)
            s.close()
        except OSError:
            pass
    out["fuzz"] = {"sent": sent}
    time.sleep(0.2)
    ent = DoIPClient.get_entity(HOST)
    c = DoIPClient(HOST, 0x1000)
    c.send_diagnostic(bytearray(b"\x22\xf1\x90"))
    out["fuzz"]["after"] = {"vin": ent[1].vin, "own_vin": bytes(c.receive_diagnostic(2.0)).hex()}
    c.close()


def main(outdir: Path) -> dict:
    subprocess.run(["ip", "link", "set", "lo", "up"], check=False)
    cfg = outdir / "gateway.toml"
    cfg.write_text(CONFIG)
    proc = subprocess.Popen([sys.executable, "-m", "vecu", "gateway", "--config", str(cfg),
                             "--duration", "120", "--no-status", "--quiet", "--summary",
                             str(outdir / "gateway.json"), "--ready-file",
                             str(outdir / "gateway.ready")],
                            stderr=open(outdir / "gateway.err", "w"))  # noqa: SIM115 - the child holds it
    out: dict = {}
    try:
        for _ in range(300):
            if (outdir / "gateway.ready").exists():
                break
            time.sleep(0.05)
        for part in (generic, versions, activation, diagnostic, flood, timers, fuzz):
            t0 = time.monotonic()
            part(out)
            out.setdefault("seconds", {})[part.__name__] = round(time.monotonic() - t0, 2)
    finally:
        out["exit"] = stop_all([proc], signal.SIGTERM, 10.0)[0]
    out["summary"] = json.loads((outdir / "gateway.json").read_text())
    out["stderr"] = (outdir / "gateway.err").read_text()[-4000:]
    return out


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
