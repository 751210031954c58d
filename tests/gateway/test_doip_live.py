"""doipclient and scapy, knowing nothing but that a DoIP gateway is on the network, against
`vecu gateway` in front of two live `vecu ecu` processes and `vecu plant` on udp_multicast
(tests/gateway/doip_live_tester.py in a private network namespace with a veth pair to broadcast
on): announcement, discovery (plain, EID, VIN), routing activation, VIN / a live DID / the DTCs
of both ECUs through udsoncan (the TPS DTC after `vecu inject` kills the sensor), a functional
request answered by both, scapy's discovery and one request."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

HERE = Path(__file__).resolve().parent
VIN = "1VECU00SIM0000001"
TPS_DTC = 0x012200


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_doip_testers_discover_the_gateway_and_diagnose_two_live_ecus_behind_it(tmp_path):
    res = run_in_namespace([sys.executable, str(HERE / "doip_live_tester.py"), str(tmp_path)],
                           timeout=240)
    assert res.returncode == 0, res.stderr + res.stdout + "".join(
        f"\n--- {p.name}\n" + p.read_text()[-2000:] for p in tmp_path.glob("*.err"))
    out = json.loads(res.stdout.strip().splitlines()[-1])
    # discovery: announcement and identification requests reach it by broadcast
    assert out["announcement"] == {"ip": "192.0.2.1", "vin": VIN, "logical_address": 0x1000}
    assert out["discovered"]["vin"] == VIN and out["discovered"]["eid"] == "020000001000"
    assert out["by_vin"] == out["by_eid"] == 0x1000
    assert out["entity_status"] == 2  # both testers' sockets active
    # both ECUs through udsoncan over DoIP
    assert out["vin"] == [VIN, VIN]
    assert out["live"] == [0, 0]  # DID 0x0105 (TPS status): ok before the kill
    for dtcs in out["dtcs"]:  # confirmed (bit 3) after the sensor died, in each ECU
        assert any(d == TPS_DTC and status & 0x08 for d, status in dtcs), dtcs
    # functional: one TesterPresent, an answer from each ECU as its own 0x8001 (and the gateway's)
    sources = {sa for sa, uds in out["functional"] if uds == "7e00"}
    assert {0x0010, 0x0011} <= sources
    assert out["scapy"]["vin"] == VIN and out["scapy"]["logical_address"] == 0x1000
    assert bytes.fromhex(out["scapy"]["rdbi"]) == b"\x62\xf1\x90" + VIN.encode()
    gw = out["gateway"]
    d = gw["doip"]
    assert d["activations"] == {"0x10": 3} and d["bad_input_total"] == 0
    assert d["handler_errors"] == {} and d["diag"]["routed"] >= 9
    routes = {r["logical_address"]: r for r in gw["routes"]["routes"]}
    assert routes[0x10]["responses"] >= 4 and routes[0x11]["responses"] >= 4
    assert gw["routes"]["functional"]["responses"] >= 2
    # the ECUs served it all over ISO-TP
    for ecu in ("ecu_a", "ecu_b"):
        uds = out[ecu]["uds"]
        assert uds["requests"] >= 4 and uds["transport_errors"] == 0
