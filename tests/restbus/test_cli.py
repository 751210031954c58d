"""`vecu restbus` on the command line: bad input is one line naming the file, the message and the
problem, exit 2, before anything is sent; a disturbance from --disturb reaches the log."""

from __future__ import annotations

import re
from pathlib import Path

import can
import pytest

from tests.cli.test_smoke import vecu

ABS = "abs.dbc"


@pytest.fixture
def files(tmp_path: Path, thirdparty: Path) -> dict[str, str]:
    def write(name: str, text: str) -> str:
        (tmp_path / name).write_text(text)
        return str(tmp_path / name)
    return {
        "abs": str(thirdparty / "dbc" / ABS),
        "motohawk": str(thirdparty / "dbc" / "motohawk.dbc"),
        "short": write("short.toml", '[[e2e]]\nmessage = "BREMSE_33"\nprofile = "P04"\n'),
        "profile": write("profile.toml", '[[e2e]]\nmessage = "BREMSE_33"\nprofile = "P09"\n'),
        "message": write("message.toml", '[[e2e]]\nmessage = "NoSuch"\nprofile = "P05"\n'),
        "range": write("range.toml", '[[value]]\nsignal = "BREMSE_33.whlspeed_FL"\n'
                                     'value = 250\n'),
        "values_kind": write("kind.toml", '[[value]]\nsignal = "BREMSE_33.whlspeed_FL"\n'
                                          'kind = "saw"\n'),
    }


CASES = [
    (["{motohawk}"], r"motohawk\.dbc: no message sent by any node has a cycle time"),
    (["{abs}", "--node", "BRAKE"], r"--node BRAKE: no such sending node in .*abs\.dbc"),
    (["{abs}", "--e2e", "{short}"],
     r"short\.toml: BREMSE_33 \(0x343\): message too short for its E2E header: P04 needs 12"),
    (["{abs}", "--e2e", "{profile}"],
     r"profile\.toml: BREMSE_33 \(0x343\): unknown E2E profile 'P09'"),
    (["{abs}", "--e2e", "{message}"], r"message\.toml: \[\[e2e\]\] #1: no message 'NoSuch'"),
    (["{abs}", "--values", "{range}"],
     r"range\.toml: BREMSE_33\.whlspeed_FL: value 250 is outside the signal's range \[0, 100\]"),
    (["{abs}", "--values", "{values_kind}"],
     r"kind\.toml: \[\[value\]\] #1 \(BREMSE_33\.whlspeed_FL\): unknown kind 'saw'"),
    (["{abs}", "--disturb", "BREMSE_33:crc_wrong@1-2"],
     r"crc_wrong on 'BREMSE_33': message BREMSE_33 has no E2E protection"),
    (["/nope.dbc"], r"/nope\.dbc: no such database file"),
]


@pytest.mark.parametrize("argv,needle", CASES, ids=[str(i) for i in range(len(CASES))])
def test_bad_input_is_one_line_naming_file_message_and_problem(argv, needle, files, tmp_path):
    log = tmp_path / "out.log"
    res = vecu("restbus", *[a.format(**files) for a in argv], "--log", str(log))
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(err) == 1, res.stderr
    assert err[0].startswith("vecu: error:") and re.search(needle, err[0]), err[0]
    assert not log.exists() or log.stat().st_size == 0  # nothing sent


def test_disturb_option_reaches_the_log_as_fi_events_and_broken_crcs(files, tmp_path):
    e2e = tmp_path / "e2e.toml"
    e2e.write_text('[[e2e]]\nmessage = "BREMSE_33"\nprofile = "P11"\n')
    log = tmp_path / "out.log"
    res = vecu("restbus", files["abs"], "--e2e", str(e2e), "--duration", "1", "--log", str(log),
               "--disturb", "BREMSE_33:crc_wrong@0.2-0.4")
    assert res.returncode == 0, res.stderr
    assert "2 disturbance events" in res.stdout
    frames = list(can.LogReader(str(log)))
    fi = [m for m in frames if m.arbitration_id == 0x6F1]
    assert [round(m.timestamp, 3) for m in fi] == [0.2, 0.4]
    import e2e as autosar_e2e
    bad = [round(m.timestamp, 3) for m in frames if m.arbitration_id == 0x343
           and not autosar_e2e.p11.e2e_p11_check(bytearray(m.data), 0x343)]
    assert bad == [round(0.2 + 0.01 * k, 3) for k in range(20)]


def test_inject_restbus_sends_an_rb_command_and_names_a_bad_target(files):
    res = vecu("inject", "--restbus", files["abs"], "--target", "BREMSE_33.whlspeed_FL",
               "--kind", "override", "--value", "12.5", "--interface", "virtual", "--channel",
               "rb-inject-smoke")
    assert res.returncode == 0, res.stderr
    assert "sent RB_Command BREMSE_33.whlspeed_FL override 12.5 on virtual" in res.stdout
    res = vecu("inject", "--restbus", files["abs"], "--target", "BREMSE_99", "--kind", "stop")
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(err) == 1
    assert "--target 'BREMSE_99': no message 'BREMSE_99' in" in err[0]
