"""DBC codecs: the one place where cantools encodes and decodes frames.

Each message is compiled once into a FrameCodec (looked up by CAN ID once per frame). Messages
with a `<prefix>_CRC` (8-bit, byte aligned) and a `<prefix>_AliveCounter` signal are E2E protected:
encode() fills the CRC, check() verifies it (vecu.e2e).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import can
import cantools
from cantools.database.can import Message

from vecu.e2e import e2e_crc

DEFAULT_DBC = "vecu.dbc"
TRUTH_DBC = "vecu_truth.dbc"  # debug truth frames, sent only when recording


class DbcLoadError(Exception):
    """A DBC file that cannot be used; the message names the file and the problem."""


def builtin_dbc_path(name: str = DEFAULT_DBC) -> Path:
    """Path of a DBC shipped with vecu (dbc/ in the source tree, vecu.dbc package data)."""
    return Path(str(resources.files("vecu.dbc").joinpath(name)))


def load_database(paths: Iterable[str | Path], strict: bool = True) -> cantools.database.Database:
    db = cantools.database.Database(strict=strict)
    for path in paths:
        try:
            db.add_dbc_file(str(path))
        except FileNotFoundError as exc:
            raise DbcLoadError(f"{path}: no such file") from exc
        except Exception as exc:  # cantools raises many kinds; report them as one line
            raise DbcLoadError(f"{path}: {type(exc).__name__}: {exc}".splitlines()[0]) from exc
    return db


@dataclass(frozen=True)
class E2ELayout:
    crc_signal: str
    counter_signal: str
    crc_byte: int


class FrameCodec:
    """Precompiled encoder/decoder for one DBC message."""

    def __init__(self, message: Message) -> None:
        self.message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.is_extended: bool = message.is_extended_frame
        self.is_fd: bool = message.is_fd
        self.length: int = message.length
        self.cycle_time_ms: int | None = message.cycle_time
        self.ranges: dict[str, tuple[float | None, float | None]] = {
            s.name: (s.minimum, s.maximum) for s in message.signals
        }
        # Only signals whose raw bits can leave the DBC range (or floats) need saturating on
        # encode and range-checking on decode; counters, CRCs and full-range enums cannot.
        self._saturate: list[tuple[str, float, float]] = []
        self._checked: list[tuple[str, float | None, float | None]] = []
        for sig in message.signals:
            lo, hi = self.ranges[sig.name]
            raw_lo, raw_hi = _raw_bounds(sig)
            if sig.is_float or (lo is not None and lo > raw_lo) or (hi is not None and hi < raw_hi) \
                    or sig.scale != 1 or sig.offset != 0:
                self._saturate.append((sig.name, *_encode_bounds(sig, lo, hi)))
            if sig.is_float or (lo is not None and lo > raw_lo) or (hi is not None and hi < raw_hi):
                self._checked.append((sig.name, lo, hi))
        self.e2e = _e2e_layout(message)
        self._encode = message.encode
        self._decode_simple = message.decode_simple

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Physical values -> payload, saturated to the DBC [minimum, maximum] (NaN -> minimum).

        The E2E CRC is filled in when the message has one.
        """
        sat = dict(values)
        for name, lo, hi in self._saturate:
            v = sat[name]
            sat[name] = lo if not v >= lo else (hi if v > hi else v)
        data = bytearray(self._encode(sat, scaling=True, padding=False, strict=False))
        if self.e2e is not None:
            data[self.e2e.crc_byte] = e2e_crc(self.frame_id, data, self.e2e.crc_byte)
        return bytes(data)

    def frame(self, values: Mapping[str, float], timestamp: float) -> can.Message:
        return can.Message(timestamp=timestamp, arbitration_id=self.frame_id,
                           is_extended_id=self.is_extended, data=self.encode(values),
                           is_fd=self.is_fd, check=False)

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        """Payload -> physical values (no choice strings). Raises on a short payload."""
        return self._decode_simple(data, False, True)

    def crc_ok(self, data: bytes | bytearray) -> bool:
        e2e = self.e2e
        if e2e is None:
            return True
        return data[e2e.crc_byte] == e2e_crc(self.frame_id, data, e2e.crc_byte)

    def bad_values(self, values: Mapping[str, float]) -> list[str]:
        """Names of signals that are NaN/inf or outside the DBC's [minimum, maximum]."""
        bad = []
        for name, lo, hi in self._checked:
            value = values.get(name)
            if value is None:
                continue
            if not math.isfinite(value) or (lo is not None and value < lo) or (
                    hi is not None and value > hi):
                bad.append(name)
        return bad


def _raw_bounds(sig) -> tuple[float, float]:
    """Physical values the signal's raw bits can express (floats: float32's range)."""
    if sig.is_float:
        return -3.0e38, 3.0e38
    if sig.is_signed:
        raw_lo, raw_hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
    else:
        raw_lo, raw_hi = 0, (1 << sig.length) - 1
    ends = sorted((raw_lo * sig.scale + sig.offset, raw_hi * sig.scale + sig.offset))
    return ends[0], ends[1]


def _encode_bounds(sig, lo: float | None, hi: float | None) -> tuple[float, float]:
    """Physical range a signal can carry: the DBC min/max, else what its raw bits allow."""
    ends = _raw_bounds(sig)
    return (ends[0] if lo is None else max(lo, ends[0]), ends[1] if hi is None else min(hi, ends[1]))


def _e2e_layout(message: Message) -> E2ELayout | None:
    crc = next((s for s in message.signals if s.name.endswith("_CRC")), None)
    counter = next((s for s in message.signals if s.name.endswith("_AliveCounter")), None)
    if crc is None or counter is None:
        return None
    if crc.length != 8 or crc.start % 8 != 0:
        raise DbcLoadError(f"{message.name}: E2E signal {crc.name} must be 8 bits, byte aligned")
    return E2ELayout(crc.name, counter.name, crc.start // 8)


class DbcCodec:
    """All messages of one or more DBC files, compiled once; lookup by name or by CAN ID.

    The default is vecu's own DBC plus its truth DBC (the ECU knows the truth IDs and ignores them).
    """

    def __init__(self, paths: Iterable[str | Path] | None = None, strict: bool = True) -> None:
        paths = (list(paths) if paths is not None
                 else [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)])
        self.paths = [str(p) for p in paths]
        self.db = load_database(paths, strict=strict)
        self._by_name = {m.name: FrameCodec(m) for m in self.db.messages}
        self.by_id: dict[tuple[int, bool], FrameCodec] = {
            (c.frame_id, c.is_extended): c for c in self._by_name.values()
        }

    def __getitem__(self, name: str) -> FrameCodec:
        return self._by_name[name]

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def lookup(self, msg: can.Message) -> FrameCodec | None:
        return self.by_id.get((msg.arbitration_id, msg.is_extended_id))
