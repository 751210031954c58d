"""The DoIP entity of `vecu gateway` against raw sockets (tests/gateway/doip_protocol_checks.py,
run once in a private network namespace): every generic NACK, routing activation code and the
diagnostic NACKs of the entity itself, with the socket closed exactly where ISO 13400-2 says;
the inactivity timers; the socket table and its alive checks; a bounded fuzz after which the
gateway still answers; and every bad input counted in the summary."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

HERE = Path(__file__).resolve().parent
pytestmark = pytest.mark.skipif(namespace_prefix()[0] is None,
                                reason=namespace_prefix()[1] or "n/a")
GENERIC = "GenericDoIPNegativeAcknowledge"
ACTIVATION = "RoutingActivationResponse"


@pytest.fixture(scope="module")
def seen(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("doip")
    res = run_in_namespace([sys.executable, str(HERE / "doip_protocol_checks.py"), str(out)],
                           timeout=120)
    assert res.returncode == 0, res.stderr + res.stdout
    return json.loads(res.stdout.strip().splitlines()[-1])


def nack(code: int) -> list:
    return [GENERIC, {"nack_code": code}]


def activation_code(obs) -> int:
    kind, fields = obs
    assert kind == ACTIVATION
    return fields["response_code"]


def test_generic_header_nacks_on_tcp_and_the_socket_closed_where_the_standard_says(seen):
    g = seen["generic"]
    assert g["pattern"] == {"answer": nack(0x00), "then": "closed"}
    assert g["default_version_on_tcp"] == {"answer": nack(0x00), "then": "closed"}
    assert g["bad_length"] == {"answer": nack(0x04), "then": "closed"}
    # unknown type, too large, out of memory: the message is skipped, the socket kept
    assert g["unknown_type"] == nack(0x01)
    assert activation_code(g["unknown_type_then_activation"]) == 0x10
    assert g["too_large"] == nack(0x02)  # 2**32 - 1 announced, never allocated
    assert g["out_of_memory"] == nack(0x03)


def test_generic_header_nacks_and_answers_on_udp(seen):
    u = seen["generic"]["udp"]
    assert u["pattern"] == nack(0x00) and u["version_ff_diagnostic"] == nack(0x00)
    assert u["unknown_type"] == nack(0x01)
    assert u["too_large"] == nack(0x02)
    assert u["bad_length"] == nack(0x04) and u["truncated"] == nack(0x04)
    assert u["version_ff_identification"][1]["vin"] == "1VECU00SIM0000001"
    assert u["by_eid"][1]["logical_address"] == 0x1000
    assert u["by_vin_other"] is None  # another vehicle's VIN: no answer
    assert u["entity_status"] == ["EntityStatusResponse", {
        "node_type": 0, "max_concurrent_sockets": 4, "currently_open_sockets": 0,
        "max_data_size": 4103}]
    assert u["power_mode"] == ["DiagnosticPowerModeResponse", {"diagnostic_power_mode": 1}]


def test_answers_carry_the_requests_protocol_version(seen):
    v = seen["versions"]
    assert v["udp_2"] == [2, 0xFD] and v["udp_3"] == [3, 0xFC] and v["tcp_3"] == [3, 0xFC]
    assert v["udp_255"] == [2, 0xFD]  # 0xFF (any version) answered in the entity's own


@pytest.mark.parametrize("code,closes", [(0x00, True), (0x02, True), (0x03, True),
                                         (0x01, True), (0x06, True), (0x04, False),
                                         (0x05, False)])
def test_every_routing_activation_code(seen, code, closes):
    obs = seen["activation"][f"0x{code:02X}"]
    assert activation_code(obs["answer"]) == code
    assert (obs["then"] == "closed") is closes


def test_activation_success_alive_checks_and_the_socket_table(seen):
    a = seen["activation"]
    assert activation_code(a["0x10"]) == 0x10 and activation_code(a["0x10_again_same_sa"]) == 0x10
    assert [activation_code(t) for t in a["table"]] == [0x10] * 4
    # alive checks went to the socket holding the SA, then to the whole table
    assert a["0x03_alive_answered"] == 1 and a["0x01_alive_answered"] == 4
    # a socket that does not answer is closed and the new tester gets its place
    assert a["0x03_silent_old_socket"] == [["AliveCheckRequest", {}], "closed"]
    assert activation_code(a["0x03_silent_then"]) == 0x10
    assert activation_code(a["0x01_silent_then"]) == 0x10
    assert a["extra_connection"] == "closed"  # beyond the table + 1: closed at once


def test_diagnostic_message_nacks_of_the_entity(seen):
    d = seen["diagnostic"]
    assert d["before_activation"]["answer"][1]["nack_code"] == 0x02
    assert d["before_activation"]["then"] == "closed"
    assert d["foreign_sa"]["answer"][1]["nack_code"] == 0x02 and d["foreign_sa"]["then"] == "closed"
    unknown = d["unknown_target"]
    assert unknown[0] == "DiagnosticMessageNegativeAcknowledgement"
    assert unknown[1]["nack_code"] == 0x03 and unknown[1]["source_address"] == 0x0777
    assert d["own_address_ack"][0] == "DiagnosticMessagePositiveAcknowledgement"
    assert d["own_address_answer"][1]["source_address"] == 0x1000
    assert "1VECU00SIM0000001" in d["own_address_answer"][1]["user_data"]


def test_a_flood_from_one_tester_gets_an_answer_for_every_request(seen):
    f = seen["flood"]
    acks = f["seen"].get("DiagnosticMessagePositiveAcknowledgement", 0)
    nacks = f["seen"].get("DiagnosticMessageNegativeAcknowledgement_0x05", 0)
    assert acks + nacks == f["sent"]  # each one acked or NACKed (out of memory), none lost
    assert f["seen"].get("DiagnosticMessage", 0) == acks  # an answer for every accepted one
    assert f["after"][0][0] == "DiagnosticMessagePositiveAcknowledgement"
    assert f["after"][1][1]["user_data"] == str(bytearray(b"\x7e\x00"))


def test_inactivity_timers_close_stalled_sockets(seen):
    t = seen["timers"]  # config: initial 0.6 s, general 1.0 s
    assert t["half_header"] == "closed" and 0.5 <= t["half_header_closed_after_s"] < 1.5
    assert t["general"] == "closed" and 0.9 <= t["general_closed_after_s"] < 2.0


def test_fuzz_finds_no_crash_and_every_bad_input_is_counted(seen):
    assert seen["fuzz"]["sent"] > 50
    after = seen["fuzz"]["after"]
    assert after["vin"] == "1VECU00SIM0000001"
    assert bytes.fromhex(after["own_vin"]) == b"\x62\xf1\x90" + b"1VECU00SIM0000001"
    assert seen["exit"] == 0
    d = seen["summary"]["doip"]
    assert d["handler_errors"] == {}
    assert "Traceback" not in seen["stderr"]
    nacks = d["generic_nacks"]
    assert all(nacks.get(f"0x{c:02X}", 0) >= 1 for c in range(5))
    bad = d["bad_input"]
    assert bad["incorrect_pattern"] == nacks["0x00"] and bad["unknown_payload_type"] == nacks["0x01"]
    assert bad["message_too_large"] == nacks["0x02"] and bad["out_of_memory"] == nacks["0x03"]
    assert bad["invalid_payload_length"] + bad["truncated_datagram"] == nacks["0x04"]
    assert d["activations"]["0x10"] >= 8 and d["diag_nacks"]["0x02"] >= 2
    assert bad["no_routing_activation"] >= 1 and bad["inactive_tester"] >= 1
    assert d["alive_checks"]["timed_out"] >= 5 and d["connections"]["refused"] >= 1
