"""Inside a private network namespace: `vecu plant`, two `vecu ecu` (0x7E0/0x7E8 and
0x7E1/0x7E9) on udp_multicast and `vecu gateway` on 0.0.0.0; then the field's DoIP testers,
knowing nothing but that a gateway is on the network: doipclient hears its announcement,
discovers it by broadcast (plain, by EID, by VIN), activates routing and, through udsoncan's
DoIPClientUDSConnector, reads the VIN, a live DID and the DTCs of both ECUs (the TPS DTC after
`vecu inject` kills the sensor); a functional request collects both answers; scapy's DoIP layer
does the discovery and one request. Prints one JSON line.
Run by tests/gateway/test_doip_live.py (python tests/gateway/doip_live_tester.py OUTDIR)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from doipclient import DoIPClient
from doipclient.connectors import DoIPClientUDSConnector
from doipclient.messages import DiagnosticMessage
from udsoncan.client import Client
from udsoncan.exceptions import TimeoutException

from tests.live.pair import start_ecu_and_plant
from tests.uds.sim import CLIENT_CONFIG
from vecu.live.scenario import stop_all

GROUP = "239.74.163.2"
BUS = ["--interface", "udp_multicast", "--channel", GROUP]
ECU_B = ["--instance", "1"]  # 0x7E1 / 0x7E9, its frames and XCP IDs apart (docs/live.md)
# a network to broadcast on, inside the namespace only (TEST-NET-1, RFC 5737): a veth pair
# (the kernel here may have no dummy driver), the limited broadcast routed onto it
NETWORK = ["ip link add v0 type veth peer name v1", "ip addr add 192.0.2.1/24 dev v0",
           "ip link set v0 up", "ip link set v1 up", "ip route add 255.255.255.255/32 dev v0"]
GATEWAY_IP = "192.0.2.1"


def wait_file(path: Path, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while not path.exists():
        if time.monotonic() > end:
            raise TimeoutError(f"{path.name} not written")
        time.sleep(0.05)


def announcement_listener() -> socket.socket:
    """UDP 13400 shared with the gateway (SO_REUSEADDR before bind: doipclient's own
    await_vehicle_announcement sets it after binding, which a second socket on the port needs)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    s.bind(("", 13400))
    s.settimeout(5.0)
    return s


def main(out: Path) -> dict:
    for cmd in NETWORK:
        subprocess.run(cmd.split(), check=True)
    vecu = [sys.executable, "-m", "vecu"]
    procs: list[subprocess.Popen] = []
    res: dict = {}

    def start(name: str, argv: list[str]) -> None:
        procs.append(subprocess.Popen([*vecu, *argv, "--ready-file", str(out / f"{name}.ready"),
                                       "--summary", str(out / f"{name}.json"), "--quiet",
                                       "--no-status"],
                                      stderr=open(out / f"{name}.err", "w")))  # noqa: SIM115 - the child holds it
        wait_file(out / f"{name}.ready")

    try:
        # the first ECU and the plant as every live test starts them, then the second ECU
        procs += start_ecu_and_plant(out, BUS, ecu_args=("--tps-timeout-cycles=100",),
                                     plant_s=110)
        start("ecu_b", ["ecu", *BUS, "--sync-timeout", "30", "--duration", "120",
                        "--tps-timeout-cycles=100", *ECU_B])
        listener = announcement_listener()
        # the shipped config, P2 raised for a loaded machine (the ECUs' 1 ms ticks may stall)
        shipped = subprocess.run([*vecu, "gateway", "--print-config"], check=True,
                                 capture_output=True, text=True).stdout
        (out / "gateway.toml").write_text(shipped.replace("p2_ms = 50.0", "p2_ms = 1500.0"))
        start("gateway", ["gateway", *BUS, "--config", str(out / "gateway.toml"),
                          "--doip-bind", "0.0.0.0", "--duration", "100"])
        addr, ann = DoIPClient.await_vehicle_announcement(sock=listener, timeout=5)
        res["announcement"] = {"ip": addr[0], "vin": ann.vin,
                               "logical_address": ann.logical_address}
        listener.close()
        ent = DoIPClient.get_entity()  # broadcast 255.255.255.255
        res["discovered"] = {"ip": ent[0][0], "vin": ent[1].vin, "eid": ent[1].eid.hex(),
                             "logical_address": ent[1].logical_address}
        res["by_vin"] = DoIPClient.get_entity(vin=ent[1].vin)[1].logical_address
        res["by_eid"] = DoIPClient.get_entity(eid=ent[1].eid)[1].logical_address
        ip = ent[0][0]
        doip_a = DoIPClient(ip, 0x0010)
        doip_b = DoIPClient(ip, 0x0011, client_logical_address=0x0E01)
        res["entity_status"] = doip_a.request_entity_status().currently_open_sockets
        config = {**CLIENT_CONFIG, "dtc_snapshot_did_size": 2}
        with Client(DoIPClientUDSConnector(doip_a), config=config) as a, \
                Client(DoIPClientUDSConnector(doip_b), config=config) as b:
            for c in (a, b):
                for _ in range(60):  # until the ECU ticks (it syncs to the plant's frames)
                    try:
                        c.tester_present()
                        break
                    except (TimeoutException, TimeoutError):
                        continue
            t0 = time.perf_counter()
            res["vin"] = [c.read_data_by_identifier(0xF190).service_data.values[0xF190]
                          for c in (a, b)]
            res["latency_ms"] = (time.perf_counter() - t0) * 1e3 / 2
            res["live"] = [c.read_data_by_identifier(0x0105).service_data.values[0x0105]
                           for c in (a, b)]
            subprocess.run([*vecu, "inject", *BUS, "--target", "tps", "--kind", "dead",
                            "--quiet"], check=True, timeout=60)
            time.sleep(0.5)
            res["dtcs"] = [[[d.id, d.status.get_byte_as_int()]
                            for d in c.get_dtc_by_status_mask(0x08).service_data.dtcs]
                           for c in (a, b)]
        # functional: one TesterPresent to 0xE400, every ECU's answer as its own 0x8001
        doip_a.send_diagnostic_to_address(0xE400, bytearray(b"\x3e\x00"))
        answers = []
        end = time.monotonic() + 3.0  # the ECUs' P2 (1.5 s here) and then some
        while time.monotonic() < end and len(answers) < 3:  # two ECUs and the gateway
            try:
                msg = doip_a.read_doip(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(msg, DiagnosticMessage):
                answers.append([msg.source_address, bytes(msg.user_data).hex()])
        res["functional"] = sorted(answers)
        doip_a.close()
        doip_b.close()
        res["scapy"] = scapy_part(ip)
    finally:
        stop_all(procs, signal.SIGTERM, 30.0)
    for name, file in (("gateway", "gateway"), ("ecu_a", "ecu"), ("ecu_b", "ecu_b")):
        p = out / f"{file}.json"
        res[name] = json.loads(p.read_text()) if p.exists() else None
    return res


def scapy_part(ip: str) -> dict:
    from scapy.contrib.automotive.doip import DoIP, UDS_DoIPSocket
    from scapy.contrib.automotive.uds import UDS, UDS_RDBI

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    s.settimeout(2.0)
    s.sendto(bytes(DoIP(payload_type=0x0001)), ("255.255.255.255", 13400))
    data, addr = s.recvfrom(1024)
    s.close()
    ann = DoIP(data)
    sock = UDS_DoIPSocket(addr[0], target_address=0x0010)
    try:
        resp = sock.sr1(UDS() / UDS_RDBI(identifiers=[0xF190]), timeout=3, verbose=False)
    finally:
        sock.close()
    return {"ip": addr[0], "vin": ann.vin.decode(), "logical_address": ann.logical_address,
            "rdbi": None if resp is None else bytes(resp).hex()}


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]))))
