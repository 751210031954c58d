"""DBC codecs: the one place where cantools encodes and decodes frames.

Each message is compiled once into a FrameCodec (looked up by CAN ID once per frame). Messages
with a `<prefix>_CRC` (8-bit, byte aligned) and a `<prefix>_AliveCounter` signal are E2E protected:
encode() fills the CRC, check() verifies it (vecu.e2e).

Fast path (docs/performance.md): for plain messages (not multiplexed, not a container, integer
or 32/64-bit float signals of either byte order that do not overlap) FrameCodec also compiles,
from cantools' own Message / Signal / conversion objects, a shift-and-mask encoder and decoder
(one generated function each, the payload as one Python int). It produces the same bytes and
values as cantools (verified bit for bit against cantools for every message of vecu's DBCs and
of the third-party DBCs, tests/test_codec_fast.py); anything it does not cover (a value that is
not a number, a raw value outside the signal's bits, a payload of the wrong length, another kind
of message) goes through cantools itself.
"""

from __future__ import annotations

import copy
import math
import struct
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
from cantools.database.can import Message
from cantools.database.conversion import (
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
)

from vecu.block_codec import (
    MAX_BLOCK_BYTES,
    BlockChecks,
    BlockField,
    BlockLayout,
    encode_rows,
)
from vecu.can_message import message
from vecu.e2e import E2EProtection, own_protection
from vecu.errors import BadFileError, ConfigError
from vecu.frame_builders import (
    DecodeParts,
    EncodeParts,
    Framer,
    compile_decode_checked,
    compile_range_check,
    make_framer,
)
from vecu.instances import ECU_NODE, ecu_frame_id

DEFAULT_DBC = "vecu.dbc"
TRUTH_DBC = "vecu_truth.dbc"  # debug truth frames, sent only when recording


class DbcLoadError(BadFileError):
    """A DBC file that cannot be used: DbcLoadError(path, problem)."""


def builtin_dbc_path(name: str = DEFAULT_DBC) -> Path:
    """Path of a DBC shipped with vecu (package data in vecu/dbc/)."""
    return Path(str(resources.files("vecu.dbc").joinpath(name)))


_ADD_BY_SUFFIX = {".arxml": "add_arxml_file", ".kcd": "add_kcd_file", ".sym": "add_sym_file"}


def load_database(paths: Iterable[str | Path], strict: bool = True) -> cantools.database.Database:
    """DBC files, or ARXML / KCD / SYM by their suffix, into one cantools database."""
    db = cantools.database.Database(strict=strict)
    for path in paths:
        try:
            getattr(db, _ADD_BY_SUFFIX.get(Path(path).suffix.lower(), "add_dbc_file"))(str(path))
        except FileNotFoundError as exc:
            raise DbcLoadError(path, "no such file") from exc
        except Exception as exc:  # cantools raises many kinds; report them as one line
            raise DbcLoadError(path, f"{type(exc).__name__}: {exc}".splitlines()[0]) from exc
    return db


@dataclass(frozen=True)
class SignalInfo:
    """One DBC signal as plain vecu data (what other modules may know of a signal)."""

    name: str
    unit: str | None
    minimum: float | None
    maximum: float | None
    scale: float
    offset: float
    length: int
    is_signed: bool
    is_float: bool


@dataclass(frozen=True)
class E2ELayout:
    """A message's `<prefix>_CRC` / `<prefix>_AliveCounter` signals and the AUTOSAR profile
    they carry (vecu.e2e.own_protection: P11, data ID = the CAN ID)."""

    crc_signal: str
    counter_signal: str
    crc_byte: int
    protection: E2EProtection


class FrameCodec:
    """Precompiled encoder/decoder for one DBC message.

    fast=False keeps only cantools' own encode/decode (the baseline of `vecu bench --only ecu`).
    """

    def __init__(self, message: Message, fast: bool = True) -> None:
        self._message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.is_extended: bool = message.is_extended_frame
        self.is_fd: bool = message.is_fd
        self.length: int = message.length
        self.cycle_time_ms: int | None = message.cycle_time
        self.senders: tuple[str, ...] = tuple(message.senders)
        self.signals: tuple[SignalInfo, ...] = tuple(
            SignalInfo(s.name, s.unit or None, s.minimum, s.maximum, s.scale, s.offset, s.length,
                       s.is_signed, s.is_float) for s in message.signals)
        self.ranges: dict[str, tuple[float | None, float | None]] = {
            s.name: (s.minimum, s.maximum) for s in message.signals
        }
        # Only signals whose raw bits can leave the DBC range (or floats) need saturating on
        # encode and range-checking on decode; counters, CRCs and full-range enums cannot.
        self._saturate: list[tuple[str, float, float]] = []
        self._checked: list[tuple[str, float | None, float | None]] = []
        self._wrap: dict[str, tuple[int, int]] = {}  # the others (counters, CRCs): lo, 2**bits
        for sig in message.signals:
            lo, hi = self.ranges[sig.name]
            raw_lo, raw_hi = _raw_bounds(sig)
            if sig.is_float or (lo is not None and lo > raw_lo) or (hi is not None and hi < raw_hi) \
                    or sig.scale != 1 or sig.offset != 0:
                self._saturate.append((sig.name, *_encode_bounds(sig, lo, hi)))
            else:
                self._wrap[sig.name] = (int(raw_lo), 1 << sig.length)
            if sig.is_float or (lo is not None and lo > raw_lo) or (hi is not None and hi < raw_hi):
                self._checked.append((sig.name, lo, hi))
        self.e2e = _e2e_layout(message)
        # what a restbus needs of the database (vecu.restbus): send type, start values,
        # multiplexer selections, an ARXML's E2E properties
        self.send_type: str | None = message.send_type
        self.start_values: dict[str, float] = {s.name: _start_value(s) for s in message.signals}
        self.mux_selections: tuple[dict[str, int], ...] = (
            tuple(_mux_selections(message.signal_tree)) if message.is_multiplexed() else ())
        self.arxml_e2e: ArxmlE2E | None = _arxml_e2e(message)
        # what a signal gateway needs (vecu.gateway.routing): each signal's choices (raw value
        # -> name), the payload bytes it occupies, and for a multiplexed signal its multiplexer
        # and the selector values that carry it
        self.choices: dict[str, dict[int, str]] = {
            s.name: {int(k): str(v) for k, v in s.choices.items()}
            for s in message.signals if s.choices}
        self.signal_bytes: dict[str, frozenset[int]] = {
            s.name: frozenset(b for b, _ in (_signal_bits(s, message.length) or ("", 0, set()))[2])
            for s in message.signals}
        self.mux_of: dict[str, tuple[str, tuple[int, ...]]] = {
            s.name: (s.multiplexer_signal, tuple(s.multiplexer_ids))
            for s in message.signals if s.multiplexer_signal is not None and s.multiplexer_ids}
        self._framers: dict[tuple[str, ...], Framer] = {}
        # crc_ok(payload): its E2E CRC byte is right (True without E2E); bad_values(values): the
        # names of signals NaN / inf or outside the DBC's [minimum, maximum]. Generated code
        # (autosar-e2e's check, vecu.frame_builders.compile_range_check): called for every frame received
        self.crc_ok: Callable[[bytes | bytearray], bool] = (
            _no_crc if self.e2e is None else self.e2e.protection.checker())
        self._protect = None if self.e2e is None else self.e2e.protection.protector()
        self.bad_values: Callable[[Mapping[str, float]], list[str]] = compile_range_check(
            self._checked, self.name)
        self._encode = message.encode
        self._decode_simple = message.decode_simple
        compiled = compile_fast_codec(message, self._saturate) if fast else None
        self._fast_encode, self._fast_decode = compiled if compiled is not None else (None, None)
        # decode() of a payload known to be `length` bytes long (the receive path checked it)
        self.decode_exact: Callable[[bytes | bytearray], dict[str, float]] = (
            self._fast_decode if self._fast_decode is not None else self.decode)
        # (decode_exact(data), bad_values of it) in one generated call: the receive path
        self.decode_checked: Callable[[bytes | bytearray], tuple[dict[str, float], list[str]]] = (
            compile_decode_checked(self.decode_exact, self._checked, self.name,
                                   complete=self._fast_decode is not None,
                                   parts=getattr(self._fast_decode, "parts", None)))
        # many payloads at once (numpy), from the same cantools layout (vecu.block_codec)
        self.block: BlockLayout | None = (block_layout(message, self.e2e)
                                          if compiled is not None else None)

    def encode_rows(self, names: Sequence[str], columns: Sequence[Any]
                    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Payloads of many frames at once (vecu.block_codec.encode_rows): row i is the
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
        restricted.bad_values = compile_range_check(restricted._checked, self.name)
        restricted.decode_checked = compile_decode_checked(
            restricted.decode_exact, restricted._checked, self.name,
            complete=restricted._fast_decode is not None,
            parts=getattr(restricted._fast_decode, "parts", None))
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
                if self._protect is None:
                    return data
                buf = bytearray(data)
                self._protect(buf)
                return bytes(buf)
        return self.encode_cantools(values)

    def encode_cantools(self, values: Mapping[str, float]) -> bytes:
        """encode() through cantools only (the reference of the fast path)."""
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

    def framer(self, names: Sequence[str]) -> Framer:
        """make(timestamp, *values): frame(dict(zip(names, values)), timestamp) in one generated
        call (vecu.frame_builders); names are all the message's signals, in the order the caller gives.
        Built once per names (runs share a codec: shared_codec)."""
        names = tuple(names)
        made = self._framers.get(names)
        if made is None:
            made = self._framers[names] = make_framer(
                self, names, getattr(self._fast_encode, "parts", None))
        return made

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
        """decode() through cantools only (the reference of the fast path)."""
        return self._decode_simple(data, False, True)



@dataclass(frozen=True)
class ArxmlE2E:
    """An ARXML message's E2E properties as cantools reads them (plain data)."""

    category: str | None
    data_ids: tuple[int, ...]
    payload_length: int | None


def _arxml_e2e(message: Message) -> ArxmlE2E | None:
    e2e = message.autosar.e2e if message.autosar is not None else None
    if e2e is None:
        return None
    return ArxmlE2E(e2e.category, tuple(e2e.data_ids or ()), e2e.payload_length)


def _start_value(sig) -> float:
    """The signal's database start value (GenSigStartValue, ARXML init value) as a physical
    number, else 0 clipped into its [minimum, maximum]."""
    raw = sig.raw_initial
    if raw is not None:
        try:
            return float(sig.conversion.raw_to_scaled(raw, decode_choices=False))
        except (TypeError, ValueError):
            pass
    lo, hi = sig.minimum, sig.maximum
    v = 0.0
    if lo is not None and v < lo:
        v = float(lo)
    if hi is not None and v > hi:
        v = float(hi)
    return v


def _mux_selections(tree: list) -> list[dict[str, int]]:
    """Every combination of multiplexer values the signal tree allows (cascades included), each
    a {multiplexer signal: value} dict, in the database's order."""
    out: list[dict[str, int]] = [{}]
    for node in tree:
        if not isinstance(node, dict):
            continue
        for mux, branches in node.items():
            options = []
            for value, sub in branches.items():
                options.extend({mux: value, **rest} for rest in _mux_selections(sub))
            out = [{**a, **b} for a in out for b in options] if options else out
    return out


def _no_crc(data: bytes | bytearray) -> bool:
    """crc_ok of a message without E2E protection."""
    return True


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


_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")


def _signal_bits(sig, n_bytes: int) -> tuple[str, int, set[tuple[int, int]]] | None:
    """("le"|"be", shift in the payload read as a little/big-endian int, (byte, bit) cells)."""
    length = sig.length
    if sig.byte_order == "little_endian":
        shift = sig.start
        cells = {((shift + i) // 8, (shift + i) % 8) for i in range(length)}
        kind = "le"
    else:  # cantools' start_bit(): network bit number of the MSB, counted from byte 0's MSB
        msb = 8 * (sig.start // 8) + (7 - sig.start % 8)
        shift = 8 * n_bytes - (msb + length)
        cells = {(n_bytes - 1 - (shift + i) // 8, (shift + i) % 8) for i in range(length)}
        kind = "be"
    if shift < 0 or shift + length > 8 * n_bytes:
        return None
    return kind, shift, cells


def compile_fast_codec(message: Message, saturate: list[tuple[str, float, float]] | None = None
                       ) -> tuple[Callable[[Mapping[str, float]], bytes | None],
                                  Callable[[bytes | bytearray], dict[str, float]]] | None:
    """(encode, decode) for a plain message, generated from cantools' signal definitions, or None.

    encode(values) applies `saturate` (name, lo, hi) like FrameCodec.encode, converts with the
    signal's own cantools conversion (LinearConversion / IdentityConversion inlined with the same
    operations, any other conversion through its bound numeric_scaled_to_raw / raw_to_scaled) and
    returns the payload, or None when a value is not a number or a raw value does not fit (the
    caller then uses cantools). decode(data) expects len(data) == message.length.
    """
    if message.is_container or message.is_multiplexed() or not message.signals:
        return None
    n = message.length
    sat = {name: (lo, hi) for name, lo, hi in (saturate or [])}
    ns: dict[str, object] = {"_NUM": (int, float), "_F32": _F32, "_F64": _F64, "_U32": _U32,
                             "_U64": _U64}
    enc = ["def encode(values):", "    le = 0", "    be = 0"]
    blocks: dict[str, list[str]] = {}
    dec = ["def decode(data):"]
    out = []
    used: set[tuple[int, int]] = set()
    kinds = set()
    for i, sig in enumerate(message.signals):
        if sig.multiplexer_ids or sig.is_multiplexer:
            return None
        placed = _signal_bits(sig, n)
        if placed is None or (sig.is_float and sig.length not in (32, 64)):
            return None
        kind, shift, cells = placed
        if cells & used:
            return None
        used |= cells
        kinds.add(kind)
        conv = sig.conversion
        # a NamedSignalConversion (choices) encodes and, without choice strings, decodes through
        # its inner numeric conversion: use that one (when this cantools version exposes it)
        inner = getattr(conv, "_conversion", None)
        if conv.choices is not None and type(inner) in (LinearConversion, IdentityConversion):
            conv = inner
        mask = (1 << sig.length) - 1
        ns[f"_sc{i}"], ns[f"_off{i}"] = conv.scale, conv.offset
        ns[f"_to_raw{i}"] = conv.numeric_scaled_to_raw
        ns[f"_to_phys{i}"] = conv.raw_to_scaled
        # ---- encode
        enc.append(f"    v = values[{sig.name!r}]")
        start = len(enc)  # this signal's lines after reading v: FrameCodec.framer reuses them
        lo, hi = ((-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed
                  else (0, mask))
        if (type(conv) is IdentityConversion and not conv.is_float and not sig.is_float
                and sig.name not in sat):
            # an int in range is its own raw value (what round() gives): no call
            enc += [f"    if v.__class__ is int and {lo} <= v <= {hi}: r = v", "    else:",
                    "        if not isinstance(v, _NUM): return None", "        r = round(v)",
                    f"        if not {lo} <= r <= {hi}: return None"]
        else:
            # a float (the usual physical value) skips the isinstance call
            enc.append("    if v.__class__ is not float and not isinstance(v, _NUM): return None")
            if sig.name in sat:
                ns[f"_lo{i}"], ns[f"_hi{i}"] = sat[sig.name]
                enc.append(f"    v = _lo{i} if not v >= _lo{i} else (_hi{i} if v > _hi{i} else v)")
            if type(conv) is LinearConversion:
                raw = f"(v - _off{i}) / _sc{i}"
                enc.append(f"    r = {raw}" if conv.is_float else f"    r = round({raw})")
            elif type(conv) is IdentityConversion:
                enc.append("    r = v" if conv.is_float else "    r = round(v)")
            else:
                enc.append(f"    r = _to_raw{i}(v)")
            if sig.is_float:
                f, u = ("_F32", "_U32") if sig.length == 32 else ("_F64", "_U64")
                enc.append(f"    r = {u}.unpack({f}.pack(r))[0]")
            else:
                enc.append(f"    if not {lo} <= r <= {hi}: return None")
        if sig.is_signed and not sig.is_float:
            enc.append(f"    r &= {mask}")
        enc.append(f"    {kind} |= r << {shift}" if shift else f"    {kind} |= r")
        blocks[sig.name] = enc[start:]
        # ---- decode
        src = f"({kind} >> {shift})" if shift else kind
        dec.append(f"    r{i} = {src} & {mask}")
        if sig.is_float:
            f, u = ("_F32", "_U32") if sig.length == 32 else ("_F64", "_U64")
            dec.append(f"    r{i} = {f}.unpack({u}.pack(r{i}))[0]")
        elif sig.is_signed:
            dec.append(f"    if r{i} > {mask >> 1}: r{i} -= {mask + 1}")
        if type(conv) is LinearConversion:
            out.append(f"{sig.name!r}: r{i} * _sc{i} + _off{i}")
        elif type(conv) is IdentityConversion:
            out.append(f"{sig.name!r}: r{i}")
        else:
            out.append(f"{sig.name!r}: _to_phys{i}(r{i}, False)")
    if kinds == {"le"}:
        enc.append(f"    return le.to_bytes({n}, 'little')")
    elif kinds == {"be"}:
        enc.append(f"    return be.to_bytes({n}, 'big')")
    else:
        enc.append(f"    return (be | int.from_bytes(le.to_bytes({n}, 'little'), 'big'))"
                   f".to_bytes({n}, 'big')")
    head = []
    if "le" in kinds:
        head.append("    le = int.from_bytes(data, 'little')")
    if "be" in kinds:
        head.append("    be = int.from_bytes(data, 'big')")
    dec[1:1] = head
    values = "{" + ", ".join(out) + "}"
    dec.append(f"    return {values}")
    code = compile("\n".join(enc + [""] + dec) + "\n", f"<vecu fast codec {message.name}>", "exec")
    exec(code, ns)  # noqa: S102 (generated from the DBC's signal layout, no user text)
    encode, decode = ns["encode"], ns["decode"]
    encode.parts = EncodeParts(blocks, enc[-1].strip()[len("return "):], ns)  # for framer()
    decode.parts = DecodeParts(dec[1:-1], values, ns)  # for decode_checked
    return encode, decode  # type: ignore[return-value]  # exec'd: typed by the generator


def block_layout(message: Message, e2e: E2ELayout | None) -> BlockLayout | None:
    """The message's BlockLayout from cantools' signals (what compile_fast_codec covers, classic
    CAN payloads, integer signals up to 32 bits, linear or identity conversions), or None."""
    n = message.length
    if n > MAX_BLOCK_BYTES or message.is_container or message.is_multiplexed():
        return None
    fields = []
    for sig in message.signals:
        placed = _signal_bits(sig, n)
        if placed is None or (not sig.is_float and sig.length > 32):
            return None
        conv = sig.conversion
        inner = getattr(conv, "_conversion", None)
        if conv.choices is not None and inner is not None:
            conv = inner  # without choice strings the named conversion decodes through it
        if type(conv) in (LinearConversion, LinearIntegerConversion):
            scale, offset = conv.scale, conv.offset
            integer = not sig.is_float and isinstance(scale, int) and isinstance(offset, int)
        elif type(conv) is IdentityConversion:
            scale = offset = None
            integer = not sig.is_float
        else:
            return None
        fields.append(BlockField(sig.name, placed[0] == "be", placed[1], sig.length,
                                 sig.is_signed, sig.length if sig.is_float else 0, scale, offset,
                                 integer, type(conv) in (LinearConversion, IdentityConversion)))
    return BlockLayout(message.frame_id, n, tuple(fields),
                       e2e.protection if e2e is not None else None)


def _e2e_layout(message: Message) -> E2ELayout | None:
    crc = next((s for s in message.signals if s.name.endswith("_CRC")), None)
    counter = next((s for s in message.signals if s.name.endswith("_AliveCounter")), None)
    if crc is None or counter is None:
        return None
    at = crc.start // 8
    if (crc.length != 8 or crc.start % 8 != 0 or counter.byte_order != "little_endian"
            or counter.start != 8 * (at + 1) or counter.length != 4 or at + 2 > message.length):
        raise DbcLoadError(None, f"{message.name}: E2E signals {crc.name} / {counter.name} must "
                           "be AUTOSAR P11's header: an 8-bit CRC byte, the 4-bit counter in the "
                           "low nibble of the next byte")
    protection = own_protection(message.frame_id & 0xFFFF)
    if at:
        protection = E2EProtection("P11", data_id=message.frame_id & 0xFFFF, offset=at)
    return E2ELayout(crc.name, counter.name, at, protection)


_SHARED: dict[tuple, DbcCodec] = {}


def shared_codec(instance: int = 0) -> DbcCodec:
    """The default DbcCodec (vecu's DBC and truth DBC) of ECU instance N (vecu.instances), built
    once per process and instance while the two files are unchanged (~30 ms a build): runs share
    it, a codec being read-only once built."""
    paths = [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)]
    try:
        stamps = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in paths)
    except OSError:  # not files on a disk: nothing to tell a change by
        return DbcCodec(paths, instance=instance)
    codec = _SHARED.get((stamps, instance))
    if codec is None:
        for key in [k for k in _SHARED if k[0] != stamps]:
            del _SHARED[key]
        codec = _SHARED[stamps, instance] = DbcCodec(paths, instance=instance)
    return codec


class DbcCodec:
    """All messages of one or more DBC files, compiled once; lookup by name or by CAN ID.

    The default is vecu's own DBC plus its truth DBC (the ECU knows the truth IDs and ignores them).
    instance: the ECU instance whose frames this codec sends or reads: every message the DBCs
    give the ECU node (VECU) as a sender is at its ID moved by vecu.instances.ecu_frame_id (its
    E2E data ID with it); 0 leaves every ID as the DBC has it.
    """

    def __init__(self, paths: Iterable[str | Path] | None = None, strict: bool = True,
                 fast: bool = True, instance: int = 0) -> None:
        paths = (list(paths) if paths is not None
                 else [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)])
        self.paths = [str(p) for p in paths]
        self.instance = instance
        self._db = load_database(paths, strict=strict)
        if instance:
            _move_ecu_frames(self._db, instance)
        self._by_name = {m.name: FrameCodec(m, fast) for m in self._db.messages}
        self.by_id: dict[tuple[int, bool], FrameCodec] = {
            (c.frame_id, c.is_extended): c for c in self._by_name.values()
        }

    def __getitem__(self, name: str) -> FrameCodec:
        return self._by_name[name]

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def lookup(self, msg: can.Message) -> FrameCodec | None:
        return self.by_id.get((msg.arbitration_id, msg.is_extended_id))

    def sent_by(self, node: str) -> set[tuple[int, bool]]:
        """(CAN ID, extended) of every message the DBC(s) give `node` as a sender."""
        return {(fc.frame_id, fc.is_extended) for fc in self._by_name.values()
                if node in fc.senders}


def _move_ecu_frames(db: cantools.database.Database, instance: int) -> None:
    """Put the ECU's messages of db at their IDs on `instance` (ConfigError when one leaves the
    ID range or lands on another message's ID)."""
    taken = {(m.frame_id, m.is_extended_frame): m.name for m in db.messages
             if ECU_NODE not in m.senders}
    for m in db.messages:
        if ECU_NODE in m.senders:
            m.frame_id = ecu_frame_id(m.frame_id, instance, m.is_extended_frame)
            key = (m.frame_id, m.is_extended_frame)
            if key in taken:
                raise ConfigError(f"ECU frame {m.name} of instance {instance} at 0x{m.frame_id:X} "
                                  f"clashes with {taken[key]}")
            taken[key] = m.name
    db.refresh()
