"""vecu.can_message.message: the can.Message python-can itself would build, field for field."""

from __future__ import annotations

import random

import can

from vecu import can_message as frames
from vecu.codec import DbcCodec


def test_this_python_can_takes_the_direct_path_and_it_builds_what_can_message_builds():
    assert frames.DIRECT  # the python-can pinned here: slots and defaults as expected
    rng = random.Random(16)
    for _ in range(300):
        kw = {"timestamp": rng.random() * 100, "arbitration_id": rng.getrandbits(29),
              "is_extended_id": rng.random() < 0.5,
              "data": (bytes if rng.random() < 0.5 else bytearray)(
                  rng.getrandbits(8) for _ in range(rng.choice([0, 1, 4, 8, 12, 64]))),
              "is_fd": rng.random() < 0.3, "channel": rng.choice([None, "vecu", 0]),
              "is_rx": rng.random() < 0.5, "bitrate_switch": rng.random() < 0.2}
        mine = frames.message(**kw)
        ref = can.Message(**kw, check=False)
        assert type(mine) is can.Message and frames.same_message(mine, ref), kw
        if type(kw["data"]) is bytearray:  # handed over, as can.Message does
            assert mine.data is kw["data"]


def test_a_codec_frame_is_the_can_message_of_its_encoding():
    codec = DbcCodec()
    tps = codec["TPS_Sensor"]
    values = {"TPS_CRC": 0, "TPS_AliveCounter": 3, "TPS_Voltage": 2.5}
    ref = can.Message(timestamp=0.25, arbitration_id=tps.frame_id, is_extended_id=False,
                      data=tps.encode(values), check=False)
    assert frames.same_message(tps.frame(values, 0.25), ref)
    assert not frames.same_message(tps.frame(values, 0.26), ref)

