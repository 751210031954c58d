"""Each message's one generated source text (vecu.codec.source, FrameCodec.source) against its
golden file, as cantools checks the C code it generates against expected files: vecu's own
messages (golden/<message>.py.txt) and a few third-party ones (golden/<dbc>/<message>.py.txt:
big-endian and signed, floats, choices, CAN FD, extended IDs, a multiplexed message that keeps
cantools). A change to the generator shows here as a diff of readable code.

After an intended change, rewrite the files and review the diff:
    VECU_UPDATE_GOLDEN=1 python -m pytest tests/codec/test_source.py
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from vecu.can_message import DIRECT
from vecu.codec import DbcCodec

GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("VECU_UPDATE_GOLDEN") == "1"
THIRDPARTY = {  # dbc -> messages (what each adds: see the module docstring)
    "motohawk.dbc": ("ExampleMessage",),
    "signed.dbc": ("Message378910",),
    "floating_point.dbc": ("Message2",),
    "choices.dbc": ("Foo",),
    "foobar.dbc": ("CanFd",),
    "big_numbers.dbc": ("TheMessage",),
    "issue_636_negative_scaling.dbc": ("ExampleMessage",),
    "padding_bit_order.dbc": ("MSG0",),
    "multiplex_2.dbc": ("Normal",),
}

pytestmark = pytest.mark.skipif(not DIRECT, reason="the golden frame() writes can.Message's "
                                "slots out; this python-can's Message takes the constructor")


def _check(path: Path, text: str) -> None:
    if UPDATE:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    assert path.is_file(), f"no golden file {path} (VECU_UPDATE_GOLDEN=1 writes it)"
    assert text == path.read_text(), f"{path.name}: generated source differs from the golden file"


def test_vecu_messages_match_their_golden_sources():
    codec = DbcCodec()
    for fc in codec.by_id.values():
        _check(GOLDEN / f"{fc.name}.py.txt", fc.source.text)
    names = {f"{fc.name}.py.txt" for fc in codec.by_id.values()}
    assert {p.name for p in GOLDEN.glob("*.py.txt")} == names  # no stale files


def test_thirdparty_messages_match_their_golden_sources(thirdparty):
    for dbc, messages in THIRDPARTY.items():
        codec = DbcCodec([thirdparty / "dbc" / dbc], strict=False)
        for name in messages:
            _check(GOLDEN / Path(dbc).stem / f"{name}.py.txt", codec[name].source.text)


def test_the_golden_source_is_the_code_that_runs():
    """The functions a FrameCodec calls come from its source text: encode, decode, the
    range check and the frame agree with what the text computes when run on its own."""
    fc = DbcCodec()["TPS_Sensor"]
    ns = dict(fc.source.namespace)
    exec(compile((GOLDEN / "TPS_Sensor.py.txt").read_text(), "<golden>", "exec"), ns)  # noqa: S102
    values = {"TPS_CRC": 0, "TPS_AliveCounter": 5, "TPS_Voltage": 6.0}  # 6 V saturates at 5
    data = fc.encode(values)
    assert ns["encode"](values) == data and fc.crc_ok(data)
    assert ns["decode_checked"](data) == fc.decode_checked(data) == (fc.decode(data), [])
    msg, carried = ns["frame"](1.5, 0, 5, 6.0)
    want = fc.framer(("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage"))(1.5, 0, 5, 6.0)
    assert msg.data == want[0].data and carried == want[1]
    assert carried == tuple(fc.decode(msg.data).values())  # CRC as protected, 5 V saturated
    assert ns["bad_values"]({"TPS_Voltage": 5.5}) == ["TPS_Voltage"]
