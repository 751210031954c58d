"""Each DoIP fault of the catalogue on the wire: the gateway's DoIP entity with the fault, a
raw-socket tester, doipclient's Parser as the oracle of what came back and when
(tests/conformance/doip_fault_checks.py, in a private network namespace), and its FI_Event
frame (FI_EvKind 31, the fault's code, the gateway's logical address)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from vecu.codec import DbcCodec
from vecu.live.netns import namespace_prefix, run_in_namespace
from vecu.uds.diag_faults.catalogue import DIAG_EV_KIND, FAULTS

HERE = Path(__file__).resolve().parent
pytestmark = [pytest.mark.skipif(namespace_prefix()[0] is None,
                                 reason=namespace_prefix()[1] or "n/a"), pytest.mark.slow]
TESTER, ECU, GATEWAY = 0x0E00, 0x0010, 0x1000


@pytest.fixture(scope="module")
def seen() -> dict:
    res = run_in_namespace([sys.executable, str(HERE / "doip_fault_checks.py")], timeout=120)
    assert res.returncode == 0, res.stderr + res.stdout
    return json.loads(res.stdout.strip().splitlines()[-1])


def kinds(obs: dict, after_ms: float = 0) -> list[str]:
    return [o[1] for o in obs["seen"] if o[0] >= after_ms]


def test_every_doip_fault_is_checked(seen):
    assert sorted(seen) == sorted(n for n, f in FAULTS.items() if f.doip)


def test_each_fault_is_an_fi_event_frame(seen):
    fc = DbcCodec()["FI_Event"]
    for name, obs in seen.items():
        ev = fc.decode(bytes.fromhex(obs["fi_event"][0]))
        assert (ev["FI_EvKind"], ev["FI_EvSignal"], ev["FI_EvActive"], ev["FI_EvMessageId"]) \
            == (DIAG_EV_KIND, FAULTS[name].code, 1, GATEWAY), name


def test_activation_refused_with_the_code(seen):
    first = seen["doip_activation_refused"]["seen"][0]
    assert first[1] == "RoutingActivationResponse" and first[2]["response_code"] == 4


def test_diag_nack_with_the_code_and_no_response(seen):
    obs = seen["doip_diag_nack"]
    after = [o for o in obs["seen"] if o[0] >= obs["sent_ms"]]
    assert [(o[1], o[2]["nack_code"]) for o in after] == [
        ("DiagnosticMessageNegativeAcknowledgement", 6)]


def test_ack_late(seen):
    obs = seen["doip_ack_late"]
    ack = next(o for o in obs["seen"] if o[1] == "DiagnosticMessagePositiveAcknowledgement")
    assert 2450 <= ack[0] - obs["sent_ms"] <= 2700  # wall clock: 2500 ms, a loaded host
    assert kinds(obs)[-1] == "DiagnosticMessage"


def test_ack_without_response(seen):
    obs = seen["doip_ack_no_response"]
    assert kinds(obs, obs["sent_ms"]) == ["DiagnosticMessagePositiveAcknowledgement"]


def test_alive_check_mid_session_and_the_testers_answer(seen):
    obs = seen["doip_alive_check"]
    assert kinds(obs, obs["sent_ms"]) == ["AliveCheckRequest",
                                          "DiagnosticMessagePositiveAcknowledgement",
                                          "DiagnosticMessage"]
    assert obs["alive_responses"] == [TESTER]


def test_connection_closed_after_the_ack(seen):
    obs = seen["doip_close_mid_response"]
    assert kinds(obs, obs["sent_ms"]) == ["DiagnosticMessagePositiveAcknowledgement", "closed"]


def test_generic_header_nack_instead_of_the_ack(seen):
    obs = seen["doip_header_nack"]
    after = [o for o in obs["seen"] if o[0] >= obs["sent_ms"]]
    assert [(o[1], o[2]["nack_code"]) for o in after] == [("GenericDoIPNegativeAcknowledge", 2)]


def test_bad_inverse_version_on_every_message(seen):
    obs = seen["doip_bad_inverse_version"]
    raw = bytes.fromhex(obs["raw"])
    assert obs["seen"] == [] and raw  # doipclient's Parser discarded every one
    i, headers = 0, []
    while i + 8 <= len(raw):
        headers.append(raw[i:i + 2])
        i += 8 + int.from_bytes(raw[i + 4:i + 8], "big")
    assert len(headers) >= 2 and all(h[1] != h[0] ^ 0xFF for h in headers)
