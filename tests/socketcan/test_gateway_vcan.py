"""`vecu gateway` and two `vecu ecu` on a real kernel's vcan0: doipclient (through udsoncan's
DoIPClientUDSConnector) reads the VIN and the confirmed DTCs (the TPS's: no plant runs) of both
ECUs over TCP on the guest's loopback, a functional
TesterPresent is answered by both, and can-utils' candump shows the ISO-TP traffic the DoIP
requests caused (single frames, the VIN's first frame, the gateway's flow control, consecutive
frames, the functional single frame). Behaviour, not timing: the emulated kernel runs Python
~20x slower, so the gateway waits P2 = 30 s."""

from __future__ import annotations

import signal
import subprocess
import sys

import can
import pytest

from tests.socketcan.kernel import CHANNEL, START_S, Processes, needs_kernel, summary

pytestmark = needs_kernel
VIN = "1VECU00SIM0000001"
ECU_B = ["--instance", "1"]  # 0x7E1 / 0x7E9, its frames and XCP IDs apart (docs/live.md)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from doipclient import DoIPClient
    from doipclient.connectors import DoIPClientUDSConnector
    from doipclient.messages import DiagnosticMessage
    from udsoncan.client import Client

    from tests.uds.sim import CLIENT_CONFIG

    out = tmp_path_factory.mktemp("gateway-vcan")
    bus = ["--interface", "socketcan", "--channel", CHANNEL]
    procs = Processes(out)
    res: dict = {"out": out}
    try:
        procs.start("candump", ["candump", "-L", CHANNEL], stdout=out / "candump.log")
        # throttle only (the emulated CPU is ~20x slower): no plant, so each ECU's TPS times
        # out and confirms its DTC, which the tester reads through the gateway
        common = [*bus, "--sync-timeout", "0", "--no-status", "--quiet", "--no-speed",
                  "--no-steering", "--no-manifold", "--tps-timeout-cycles", "50"]
        for name, more in (("ecu_a", []), ("ecu_b", ECU_B)):
            procs.vecu(name, "ecu", *common, *more, "--ready-file", str(out / f"{name}.ready"),
                       "--summary", str(out / f"{name}.json"))
            procs.ready(name, out / f"{name}.ready")
        shipped = subprocess.run([sys.executable, "-m", "vecu", "gateway", "--print-config"],
                                 check=True, capture_output=True, text=True).stdout
        (out / "gw.toml").write_text(shipped.replace("p2_ms = 50.0", "p2_ms = 30000.0").replace(
            "p2_star_ms = 5000.0", "p2_star_ms = 60000.0"))
        procs.vecu("gateway", "gateway", *bus, "--config", str(out / "gw.toml"), "--no-status",
                   "--ready-file", str(out / "gw.ready"), "--summary", str(out / "gw.json"))
        procs.ready("gateway", out / "gw.ready")
        config = {**CLIENT_CONFIG, "request_timeout": START_S, "p2_timeout": START_S,
                  "p2_star_timeout": START_S}
        vins, dtcs = [], []
        for la, sa in ((0x0010, 0x0E00), (0x0011, 0x0E01)):
            doip = DoIPClient("127.0.0.1", la, client_logical_address=sa)
            with Client(DoIPClientUDSConnector(doip, close_connection=True), config=config) as c:
                vins.append(c.read_data_by_identifier(0xF190).service_data.values[0xF190])
                dtcs.append([d.id for d in c.get_dtc_by_status_mask(0x08).service_data.dtcs])
        res["vins"], res["dtcs"] = vins, dtcs
        doip = DoIPClient("127.0.0.1", 0x0010, client_logical_address=0x0E02)
        doip.send_diagnostic_to_address(0xE400, bytearray(b"\x3e\x00"), timeout=START_S)
        answers = set()
        while len(answers) < 3:  # both ECUs and the gateway itself
            msg = doip.read_doip(timeout=START_S)
            if isinstance(msg, DiagnosticMessage):
                answers.add((msg.source_address, bytes(msg.user_data)))
        doip.close()
        res["functional"] = answers
        for name in ("gateway", "ecu_b", "ecu_a"):
            res[f"{name}_exit"] = procs.stop(name)
        procs.stop("candump", signal.SIGINT)
    finally:
        procs.close()
    return res


def test_doipclient_reads_both_ecus_vin_through_the_gateway_on_vcan0(session):
    assert session["vins"] == [VIN, VIN]
    assert all(0x012087 in ids for ids in session["dtcs"]), session["dtcs"]  # TPS timeout: no plant
    assert {sa for sa, uds in session["functional"] if uds == b"\x7e\x00"} >= {0x10, 0x11}
    assert session["gateway_exit"] == 0
    gw = summary(session["out"] / "gw.json")
    routes = {r["logical_address"]: r for r in gw["routes"]["routes"]}
    assert routes[0x10]["responses"] >= 1 and routes[0x11]["responses"] >= 1
    assert gw["doip"]["activations"] == {"0x10": 3} and gw["doip"]["handler_errors"] == {}
    # candump: the ISO-TP traffic the DoIP requests caused, in the kernel's own record
    frames = [(m.arbitration_id, bytes(m.data))
              for m in can.LogReader(str(session["out"] / "candump.log"))]
    for req, resp in ((0x7E0, 0x7E8), (0x7E1, 0x7E9)):
        assert (req, bytes.fromhex("0322f190cccccccc")) in frames  # RDBI F190, a single frame
        first = [d for i, d in frames if i == resp and d[:1] == b"\x10"]  # the answer's FF
        assert first and first[0][:5] == bytes.fromhex("1014") + b"\x62\xf1\x90"
        assert any(i == req and d[0] == 0x30 for i, d in frames)  # the gateway's flow control
        assert any(i == resp and d[0] == 0x21 for i, d in frames)  # consecutive frames
    assert (0x7DF, bytes.fromhex("023e00cccccccccc")) in frames  # the functional single frame
