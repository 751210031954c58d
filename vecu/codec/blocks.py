"""Block decoding and encoding: many payloads of one CAN message at once, with numpy.

The bit layout comes from cantools (block_layout: start bit, length, byte order, sign, float or
integer, scale and offset of each signal, taken from cantools' Signal and conversion objects
once; no DBC text is parsed here). For N payloads of the message's length,
check() extracts every signal of every payload with shifts and masks on 64-bit words, applies
the same conversion with the same IEEE operations as the per-frame decoder (so the values are
bit for bit FrameCodec.decode's, ints where it gives ints), and checks the E2E CRC and the DBC
ranges of all of them vectorised. Only classic CAN payloads (at most 8 bytes) with linear or
identity conversions get a layout; anything else stays on the per-frame path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from cantools.database.can import Message
from cantools.database.conversion import (
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
)

from vecu.codec.e2e_layout import E2ELayout
from vecu.codec.signals import numeric_conversion, signal_bits
from vecu.e2e import E2EProtection

MAX_BLOCK_BYTES = 8


@dataclass(frozen=True)
class BlockField:
    """One signal: where its raw bits are and how they become the value."""

    name: str
    big_endian: bool       # shift counts in the payload read as a big-endian integer
    shift: int
    length: int
    signed: bool
    float_bits: int        # 32 / 64 for IEEE float signals, 0 for integers
    scale: float | int | None  # None: identity (the raw value itself)
    offset: float | int | None
    integer: bool          # the per-frame decoder gives a Python int
    encodable: bool = True  # the per-frame encoder inlines its conversion (encode_rows takes it)


@dataclass(frozen=True)
class BlockChecks:
    """What BlockLayout.check found for each payload (block[i]: CRC ok, values, bad signals)."""

    crc_ok: list[bool]
    names: list[str]
    columns: list[list[float]]  # per signal, the values of all payloads (Python floats / ints)
    bad: dict[int, list[str]]
    rows: list[tuple] = field(init=False, repr=False)  # per payload its values (zip of columns)

    def __post_init__(self) -> None:
        rows = list(zip(*self.columns)) if self.columns else [()] * len(self.crc_ok)
        object.__setattr__(self, "rows", rows)

    def __len__(self) -> int:
        return len(self.crc_ok)

    def __getitem__(self, i: int) -> tuple[bool, dict[str, float], list[str]]:
        """(CRC ok, values, bad signals) of payload i; the values dict is made now, when the
        frame is used (a block of live dicts would keep the garbage collector busy)."""
        return self.crc_ok[i], dict(zip(self.names, self.rows[i])), self.bad.get(i, [])


@dataclass(frozen=True)
class BlockLayout:
    """All signals of one message and its E2E CRC position (None: not E2E protected)."""

    frame_id: int
    length: int
    fields: tuple[BlockField, ...]
    e2e: E2EProtection | None

    def check(self, payloads: Sequence[bytes | bytearray],
              checked: Sequence[tuple[str, float | None, float | None]]) -> BlockChecks:
        """CRC verdicts, values and the names of signals NaN/inf or outside [lo, hi] of every
        payload, as FrameCodec.crc_ok / decode / bad_values give them one by one (`checked`:
        the codec's range-checked signals). Every payload must be `length` bytes long."""
        n, size = len(payloads), self.length
        if n == 0:
            return BlockChecks([], [], [], {})
        raw = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(n, size)
        words = {}
        if any(not f.big_endian for f in self.fields):
            buf = np.zeros((n, 8), dtype=np.uint8)
            buf[:, :size] = raw
            words[False] = buf.view("<u8").ravel()
        if any(f.big_endian for f in self.fields):
            buf = np.zeros((n, 8), dtype=np.uint8)
            buf[:, 8 - size:] = raw
            words[True] = buf.view(">u8").ravel().astype(np.uint64)
        columns: list[np.ndarray] = []
        for f in self.fields:
            bits = (words[f.big_endian] >> np.uint64(f.shift)) & np.uint64((1 << f.length) - 1)
            if f.float_bits == 32:
                with np.errstate(invalid="ignore"):  # signalling NaNs stay NaN, as in struct
                    col = bits.astype(np.uint32).view(np.float32).astype(np.float64)
            elif f.float_bits == 64:
                col = bits.view(np.float64)
            else:
                col = bits.astype(np.int64)
                if f.signed:
                    col = np.where(col >= (1 << (f.length - 1)), col - (1 << f.length), col)
            if f.scale is not None:
                if f.integer:
                    col = col * f.scale + f.offset
                else:
                    col = col.astype(np.float64) * f.scale + f.offset
            columns.append(col)
        if self.e2e is not None:  # the library's check, row by row
            check = self.e2e.checker()
            ok = [check(bytearray(row)) for row in raw]
        else:
            ok = [True] * n
        index = {f.name: i for i, f in enumerate(self.fields)}
        bad_masks = []
        for name, lo, hi in checked:
            v = columns[index[name]]
            mask = ~np.isfinite(v) if v.dtype.kind == "f" else np.zeros(n, dtype=bool)
            if lo is not None:
                mask |= v < lo
            if hi is not None:
                mask |= v > hi
            bad_masks.append((name, mask))
        names = [f.name for f in self.fields]
        bad: dict[int, list[str]] = {}
        if bad_masks:
            any_bad = np.logical_or.reduce([mask for _, mask in bad_masks])
            for i in np.flatnonzero(any_bad).tolist():
                bad[i] = [name for name, mask in bad_masks if mask[i]]
        return BlockChecks(ok, names, [c.tolist() for c in columns], bad)


def encode_rows(layout: BlockLayout, columns: Sequence[np.ndarray],
                saturate: Mapping[str, tuple[float, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """Payloads of many frames at once: row i of the (n, length) uint8 array is what
    FrameCodec.framer's make gives for the values columns[j][i] of the layout's fields (in
    layout order): saturated like the codec's encoder (`saturate`: name -> (lo, hi)), rounded
    half to even as Python's round(), the E2E CRC written last. The mask marks rows it did not
    encode (a value not finite, a raw value that does not fit: the per-frame path decides
    those). None: a field it does not take (a conversion the encoder does not inline)."""
    if not all(f.encodable for f in layout.fields):
        return None
    n, size = len(columns[0]), layout.length
    refused = np.zeros(n, dtype=bool)
    words = {False: np.zeros(n, dtype=np.uint64), True: np.zeros(n, dtype=np.uint64)}
    with np.errstate(invalid="ignore"):
        for f, col in zip(layout.fields, columns):
            v = np.asarray(col, dtype=np.float64)
            if f.name in saturate:  # v = lo if not v >= lo else (hi if v > hi else v)
                lo, hi = saturate[f.name]
                v = np.where(~(v >= lo), lo, np.where(v > hi, hi, v))
            x = v if f.scale is None else (v - f.offset) / f.scale
            if f.float_bits:  # struct.pack: a finite value too large for float32 is refused
                as_float = x.astype(np.float32) if f.float_bits == 32 else x
                refused |= ~np.isfinite(as_float)
                bits = as_float.view(np.uint32 if f.float_bits == 32 else np.uint64)
                bits = np.where(refused, 0, bits).astype(np.uint64)
                words[f.big_endian] |= bits << np.uint64(f.shift)
                continue
            r = np.rint(x)
            lo_raw, hi_raw = ((-(1 << (f.length - 1)), (1 << (f.length - 1)) - 1) if f.signed
                              else (0, (1 << f.length) - 1))
            refused |= ~((r >= lo_raw) & (r <= hi_raw))  # NaN and inf included
            raw = np.where(refused, 0.0, r).astype(np.int64) & ((1 << f.length) - 1)
            words[f.big_endian] |= raw.astype(np.uint64) << np.uint64(f.shift)
    out = words[False].astype("<u8").view(np.uint8).reshape(n, 8)[:, :size].copy()
    if any(f.big_endian for f in layout.fields):
        out |= words[True].astype(">u8").view(np.uint8).reshape(n, 8)[:, 8 - size:]
    if layout.e2e is not None:  # the library's protect, row by row, in place
        protect = layout.e2e.protector()
        for row in out:
            protect(row)
    return out, refused


def block_layout(message: Message, e2e: E2ELayout | None) -> BlockLayout | None:
    """The message's BlockLayout from cantools' signals (plain layouts of classic CAN payloads,
    integer signals up to 32 bits, linear or identity conversions), or None."""
    n = message.length
    if n > MAX_BLOCK_BYTES or message.is_container or message.is_multiplexed():
        return None
    fields = []
    for sig in message.signals:
        placed = signal_bits(sig, n)
        if placed is None or (not sig.is_float and sig.length > 32):
            return None
        conv = numeric_conversion(sig)
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
