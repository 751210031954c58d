"""Property tests: whatever a consumed frame carries inside its DBC range (and raw extremes), a
real EcuNode tick never raises and never broadcasts a non-finite value (issue 14, items 1-2)."""

from __future__ import annotations

import math
from collections import deque

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vecu.assembly import build_functions
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec, FrameCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode

PROPERTY = settings(max_examples=40, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])
TICKS_PER_FRAME = 10  # every function (steering: 10 ms) runs after each frame


class QueueBus:
    """The ECU's side of a bus: frames put() are received, sent frames are dropped."""

    def __init__(self) -> None:
        self.rx: deque[can.Message] = deque()

    def put(self, msg: can.Message) -> None:
        self.rx.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.rx.popleft() if self.rx else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


class Recording:
    """A FrameCodec whose frame() also records the physical values it was asked to send."""

    def __init__(self, fc: FrameCodec, sink: list[tuple[str, dict[str, float]]]) -> None:
        self._fc, self._sink = fc, sink

    def __getattr__(self, name: str):
        return getattr(self._fc, name)

    def frame(self, values, timestamp: float) -> can.Message:
        self._sink.append((self._fc.name, dict(values)))
        return self._fc.frame(values, timestamp)


class RecordingCodec(DbcCodec):
    """vecu's DBC; the messages the ECU sends record their values before encoding."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: list[tuple[str, dict[str, float]]] = []

    def __getitem__(self, name: str):
        fc = super().__getitem__(name)
        return Recording(fc, self.sent) if "VECU" in fc.senders else fc


CODEC = RecordingCodec()
FUNCTIONS = build_functions(RunConfig(), CODEC).enabled()
CONSUMED = sorted({sub.message for fn in FUNCTIONS for sub in fn.subscriptions()})


def make_ecu() -> tuple[EcuNode, QueueBus]:
    CODEC.sent.clear()
    bus = QueueBus()
    return EcuNode(bus, CODEC, build_functions(RunConfig(), CODEC).enabled()), bus  # type: ignore[arg-type]  # a queue standing in for the bus


def feed(payloads: list[bytes], message: str) -> EcuNode:
    """Each payload as one frame of `message`, followed by TICKS_PER_FRAME ECU ticks; asserts
    that no broadcast carried a non-finite value."""
    ecu, bus = make_ecu()
    fc = CODEC[message]
    t = 0
    for data in payloads:
        bus.put(can.Message(arbitration_id=fc.frame_id, is_extended_id=fc.is_extended,
                            data=data, timestamp=t / 1e9))
        for _ in range(TICKS_PER_FRAME):
            ecu.tick(t)
            t += NS_PER_MS
    bad = [(name, k, v) for name, values in CODEC.sent for k, v in values.items()
           if not math.isfinite(v)]
    assert not bad, f"non-finite broadcast: {bad[:5]}"
    assert CODEC.sent, "the ECU sent nothing"
    return ecu


def in_range(sig) -> st.SearchStrategy[float]:
    lo, hi = sig.minimum, sig.maximum
    return st.one_of(st.sampled_from([lo, hi]),
                     st.floats(lo, hi, allow_nan=False, allow_infinity=False))


def frames_of(message: str) -> st.SearchStrategy[list[bytes]]:
    """1-4 frames, every signal anywhere in its DBC range; E2E alive counters consecutive so
    that each frame reaches the function."""
    fc = CODEC[message]
    frame = st.fixed_dictionaries({s.name: in_range(s) for s in fc.signals})

    def encode(frames: list[dict[str, float]]) -> list[bytes]:
        out = []
        for i, drawn in enumerate(frames):
            values = dict(drawn)
            if fc.e2e is not None:
                values[fc.e2e.counter_signal] = i % fc.e2e.protection.counter_modulo
            out.append(fc.encode(values))
        return out

    return st.lists(frame, min_size=1, max_size=4).map(encode)


@pytest.mark.parametrize("message", CONSUMED)
def test_any_in_range_frame_of_a_consumed_message_is_survived(message):
    @PROPERTY
    @given(frames_of(message))
    def check(payloads: list[bytes]) -> None:
        feed(payloads, message)

    check()


def raw_extremes(fc: FrameCodec) -> list[bytes]:
    """All-zero and all-0xFF payloads, and each signal at its minimum and maximum (the others
    at theirs), as raw bytes; E2E payloads also with a valid CRC."""
    out = [bytes(fc.length), b"\xff" * fc.length]
    for pick in (0, 1):
        out.append(fc.encode({s.name: (s.minimum, s.maximum)[pick] for s in fc.signals}))
    if fc.e2e is not None:
        for data in out[:2]:
            buf = bytearray(data)
            fc.e2e.protection.protector()(buf)  # autosar-e2e writes the CRC
            out.append(bytes(buf))
    return out


@pytest.mark.parametrize("message", CONSUMED)
def test_raw_extremes_of_a_consumed_message_are_survived(message):
    for data in raw_extremes(CODEC[message]):
        feed([data, data, data], message)
