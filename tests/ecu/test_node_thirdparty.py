"""Real traces nobody here wrote (python-can's and cantools' test data) fed into the ECU."""

from __future__ import annotations

import can

from vecu.bus import open_bus
from vecu.codec import DbcCodec
from vecu.ecu.node import EcuNode
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.registry import make_throttle_estimator

LOG_SUFFIXES = (".asc", ".blf", ".trc", ".gz")


def _frames(path):
    with can.LogReader(str(path)) as reader:
        return list(reader)


def test_every_third_party_log_goes_through_the_ecu_counted_and_without_error(thirdparty):
    logs = sorted(p for p in (thirdparty / "logs").iterdir() if p.name.endswith(LOG_SUFFIXES))
    assert len(logs) >= 10
    codec = DbcCodec()
    total = 0
    for path in logs:
        frames = _frames(path)
        assert frames, path.name
        bus = open_bus(channel=f"thirdparty-{path.name}")
        try:
            ecu = EcuNode(bus, codec, [ThrottleFunction(codec, make_throttle_estimator("arm")),
                                      SpeedFunction(codec)])
            for k, msg in enumerate(frames):
                ecu.receive(msg, k * 1_000_000)
                if k % 10 == 0:
                    ecu.tick(k * 1_000_000)
            rx = ecu.rx
            assert rx.received == len(frames)
            # every frame in exactly one bin
            assert rx.accepted + rx.ignored + rx.rejected == rx.received, path.name
            assert rx.malformed == 0, path.name
            assert ecu.frames_sent > 0
            total += len(frames)
        finally:
            bus.shutdown()
    assert total > 1500


def test_error_and_remote_frames_from_a_real_asc_are_binned(thirdparty):
    frames = _frames(thirdparty / "logs" / "pythoncan_logfile_errorframes.asc")
    errors = sum(1 for m in frames if m.is_error_frame)
    remotes = sum(1 for m in frames if m.is_remote_frame)
    assert errors > 0
    bus = open_bus(channel="thirdparty-err")
    try:
        codec = DbcCodec()
        ecu = EcuNode(bus, codec, [ThrottleFunction(codec, make_throttle_estimator("arm"))])
        for msg in frames:
            ecu.receive(msg, 0)
        assert ecu.rx.error_frames == errors
        assert ecu.rx.remote_frames <= remotes  # remote frames on IDs we do not consume count as unknown
    finally:
        bus.shutdown()
