"""FrameCodec: one DBC message compiled once (its generated source, vecu.codec.source), looked
up by CAN ID once per frame. Messages with a `<prefix>_CRC` (8-bit, byte aligned) and a
`<prefix>_AliveCounter` signal are E2E protected: encode() fills the CRC, crc_ok() verifies it.

The generated functions give the same bytes and values as cantools (bit for bit against
cantools for every message of vecu's DBCs and of the third-party DBCs, tests/codec/); anything
they do not cover (a value that is not a number, a raw value outside the signal's bits, a
payload of the wrong length, a multiplexed message or a container) goes through cantools.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import can
import numpy as np
from cantools.database.can import Message

from vecu.can_message import Values, message
from vecu.codec.blocks import BlockChecks, BlockLayout, block_layout, encode_rows
from vecu.codec.e2e_layout import e2e_layout
from vecu.codec.signals import (
    ArxmlE2E,
    SignalInfo,
    arxml_e2e,
    mux_selections,
    signal_bits,
    signal_info,
    signal_ranges,
    start_value,
)
from vecu.codec.source import MessageSource, compile_source, message_source

# make(timestamp, *values in the message's signal order) -> (frame, the values it carries)
Framer = Callable[..., tuple[can.Message, Values]]


class FrameCodec:
    """Precompiled encoder/decoder for one DBC message.

    fast=False keeps only cantools' own encode/decode (the baseline of `vecu bench --only ecu`).
    """

    def __init__(self, msg: Message, fast: bool = True) -> None:
        self._message = msg
        self.name: str = msg.name
        self.frame_id: int = msg.frame_id
        self.is_extended: bool = msg.is_extended_frame
        self.is_fd: bool = msg.is_fd
        self.length: int = msg.length
        self.cycle_time_ms: int | None = msg.cycle_time
        self.senders: tuple[str, ...] = tuple(msg.senders)
        self.signals: tuple[SignalInfo, ...] = tuple(signal_info(s) for s in msg.signals)
        self.ranges: dict[str, tuple[float | None, float | None]] = {
            s.name: (s.minimum, s.maximum) for s in msg.signals}
        ranges = signal_ranges(msg)
        self._saturate = list(ranges.saturate)
        self._checked = list(ranges.checked)
        self._wrap = ranges.wrap
        self.e2e = e2e_layout(msg)
        # what a restbus needs of the database (vecu.restbus): send type, start values,
        # multiplexer selections, an ARXML's E2E properties
        self.send_type: str | None = msg.send_type
        self.start_values: dict[str, float] = {s.name: start_value(s) for s in msg.signals}
        self.mux_selections: tuple[dict[str, int], ...] = (
            tuple(mux_selections(msg.signal_tree)) if msg.is_multiplexed() else ())
        self.arxml_e2e: ArxmlE2E | None = arxml_e2e(msg)
        # what a signal gateway needs (vecu.gateway.routing): each signal's choices (raw value
        # -> name), the payload bytes it occupies, and for a multiplexed signal its multiplexer
        # and the selector values that carry it
        self.choices: dict[str, dict[int, str]] = {
            s.name: {int(k): str(v) for k, v in s.choices.items()}
            for s in msg.signals if s.choices}
        self.signal_bytes: dict[str, frozenset[int]] = {
            s.name: frozenset(b for b, _ in (signal_bits(s, msg.length) or ("", 0, set()))[2])
            for s in msg.signals}
        self.mux_of: dict[str, tuple[str, tuple[int, ...]]] = {
            s.name: (s.multiplexer_signal, tuple(s.multiplexer_ids))
            for s in msg.signals if s.multiplexer_signal is not None and s.multiplexer_ids}
        # crc_ok(payload): its E2E CRC byte is right (True without E2E; autosar-e2e's check)
        self.crc_ok: Callable[[bytes | bytearray], bool] = (
            _no_crc if self.e2e is None else self.e2e.protection.checker())
        self._protect = None if self.e2e is None else self.e2e.protection.protector()
        self._encode = msg.encode
        self._decode_simple = msg.decode_simple
        self._fast = fast
        self._compile()
        # many payloads at once (numpy), from the same cantools layout (vecu.codec.blocks)
        self.block: BlockLayout | None = (block_layout(msg, self.e2e)
                                          if self.source.plain else None)

    def _compile(self) -> None:
        """The message's generated source (its range check: self._checked) and its functions:
        bad_values(values), the names of signals NaN / inf or outside the DBC's [minimum,
        maximum]; decode_exact(data) of a payload known to be `length` bytes long (the receive
        path checked it); decode_checked(data) = (decode_exact(data), bad_values of it)."""
        self.source: MessageSource = message_source(
            self._message, saturate=self._saturate, checked=self._checked,
            protect=self._protect, decode_fallback=self.decode_cantools,
            frame_fallback=self._frame_row, plain=self._fast,
            header=(None if self.e2e is None else
                    (self.e2e.crc_signal, self.e2e.counter_signal, self.e2e.crc_byte)))
        made = compile_source(self.source)
        self._fast_encode, self._fast_decode, self._frame = made.encode, made.decode, made.frame
        self.bad_values: Callable[[Mapping[str, float]], list[str]] = made.bad_values
        self.decode_exact: Callable[[bytes | bytearray], dict[str, float]] = (
            made.decode if made.decode is not None else self.decode)
        self.decode_checked: Callable[[bytes | bytearray], tuple[dict[str, float], list[str]]] = (
            made.decode_checked)

    def encode_rows(self, names: Sequence[str], columns: Sequence[Any]
                    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Payloads of many frames at once (vecu.codec.blocks.encode_rows): row i is the
        payload framer(names)'s make(ts, *(c[i] for c in columns)) sends, the mask the rows left
        to make(); None when the message's layout is not one the block encoder takes."""
        if self.block is None:
            return None
        by_name = dict(zip(names, columns))
        return encode_rows(self.block, [by_name[f.name] for f in self.block.fields],
                           {name: (lo, hi) for name, lo, hi in self._saturate})

    def signal(self, name: str) -> SignalInfo:
        """The named signal (KeyError when the message has none)."""
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise KeyError(f"{self.name} has no signal {name!r}")

    def checking_only(self, signals: Iterable[str]) -> FrameCodec:
        """This codec, range-checking (bad_values) only the given signals; encode/decode alike."""
        keep = set(signals)
        restricted = copy.copy(self)
        restricted._checked = [c for c in self._checked if c[0] in keep]
        restricted._compile()
        return restricted

    def fit(self, name: str, value: float) -> float:
        """`value` as signal `name` can carry it (a fault pushed it anywhere): a signal whose DBC
        range is its whole raw range (counters, CRCs: integer, scale 1, offset 0) wraps modulo
        2**bits (255 + 1 -> 0); any other saturates at its DBC minimum / maximum as encode() does
        (NaN: the minimum). A non-finite value on a wrapping signal saturates too."""
        wrap = self._wrap.get(name)
        if wrap is None:
            for sat_name, lo, hi in self._saturate:
                if sat_name == name:
                    return lo if not value >= lo else min(value, hi)
            raise KeyError(f"{self.name} has no signal {name!r}")
        lo_w, modulus = wrap
        if math.isfinite(value):
            return lo_w + (round(value) - lo_w) % modulus
        return lo_w if not value >= lo_w else lo_w + modulus - 1

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Physical values -> payload, saturated to the DBC [minimum, maximum] (NaN -> minimum).

        The E2E CRC is filled in when the message has one.
        """
        fast = self._fast_encode
        if fast is not None:
            try:
                data = fast(values)
            except Exception:  # noqa: BLE001 (anything unusual: cantools decides, raises its own)
                data = None
            if data is not None:
                return data
        return self.encode_cantools(values)

    def encode_cantools(self, values: Mapping[str, float]) -> bytes:
        """encode() through cantools only (the reference of the generated encoder)."""
        sat = dict(values)
        for name, lo, hi in self._saturate:
            v = sat[name]
            sat[name] = lo if not v >= lo else min(v, hi)
        data = bytearray(self._encode(sat, scaling=True, padding=False, strict=False))
        if self._protect is not None:
            self._protect(data)
        return bytes(data)

    def frame(self, values: Mapping[str, float], timestamp: float) -> can.Message:
        """encode(values) as a can.Message (vecu.can_message.message: the fields can.Message gives)."""
        return message(timestamp, self.frame_id, self.is_extended, self.encode(values),
                       self.is_fd)

    def _frame_row(self, timestamp: float, values: tuple) -> tuple[can.Message, Values]:
        """frame()'s row of values the generated lines do not take: cantools encodes, and the
        values are those of its payload (None: a multiplexed signal it does not carry; all
        None when cantools cannot decode what it encoded, a multiplexer value it does not know)."""
        names = [s.name for s in self.signals]
        msg = self.frame(dict(zip(names, values)), timestamp)
        decoded = {} if self.decode_problem(msg.data) else self.decode(msg.data)
        return msg, tuple(decoded.get(name) for name in names)

    def framer(self, names: Sequence[str]) -> Framer:
        """make(timestamp, *values) -> (frame(dict(zip(names, values)), timestamp), the values
        as that frame carries them: decode() of its payload, in the same order, computed from
        the raw values encoded) in one generated call (the source's frame()); names must be the
        message's signals in the DBC's order, the order the caller passes the values in (a
        ValueError otherwise)."""
        if tuple(names) != tuple(s.name for s in self.signals):
            raise ValueError(f"{self.name}: framer names {list(names)} are not its signals in "
                             f"the DBC's order {[s.name for s in self.signals]}")
        return self._frame

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        """Payload -> physical values (no choice strings). Raises on a short payload."""
        fast = self._fast_decode
        if fast is not None and len(data) == self.length:
            return fast(data)
        return self._decode_simple(data, False, True)

    def check_block(self, payloads: list[bytes | bytearray]) -> BlockChecks | None:
        """crc_ok, decode and bad_values of many payloads of this message's length at once (the
        same as those three calls per payload); None when the message has no block layout."""
        if self.block is None:
            return None
        return self.block.check(payloads, self._checked)

    def decode_problem(self, data: bytes | bytearray) -> str | None:
        """Why decode(data) fails (the exception's name), None when it works. A payload of the
        message's length that the generated decoder takes is not decoded at all: shifts, masks
        and linear or cantools conversions of in-range integers cannot fail."""
        if self._fast_decode is not None and len(data) == self.length:
            return None
        try:
            self.decode(data)
        except Exception as exc:  # noqa: BLE001 - whatever cantools raises for this payload
            return type(exc).__name__
        return None

    def decode_cantools(self, data: bytes | bytearray) -> dict[str, float]:
        """decode() through cantools only (the reference of the generated decoder)."""
        return self._decode_simple(data, False, True)


def _no_crc(data: bytes | bytearray) -> bool:
    """crc_ok of a message without E2E protection."""
    return True
