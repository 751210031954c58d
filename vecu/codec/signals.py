"""What the codec reads of a DBC signal once (cantools' Signal): its plain-data description
(SignalInfo), where its raw bits sit in the payload, the physical range its bits carry, and the
per-message lists of signals that saturate on encode, are range-checked on receive, or wrap."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cantools.database.can import Message


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

    @property
    def integral(self) -> bool:
        """Its physical values are whole numbers (an integer raw value, integer scale and
        offset): what an integer or Boolean variable can take."""
        return (not self.is_float and float(self.scale).is_integer()
                and float(self.offset).is_integer())


@dataclass(frozen=True)
class ArxmlE2E:
    """An ARXML message's E2E properties as cantools reads them (plain data)."""

    category: str | None
    data_ids: tuple[int, ...]
    payload_length: int | None


Bounds = tuple[str, float | None, float | None]  # (signal name, lo, hi); None: no bound


@dataclass(frozen=True)
class SignalRanges:
    """A message's signals by how their DBC range acts: `saturate` (name, lo, hi) on encode,
    `checked` (name, lo, hi) on receive, `wrap` name -> (lo, 2**bits) for the others (counters,
    CRCs, full-range enums: their raw bits cannot leave the DBC range)."""

    saturate: tuple[tuple[str, float, float], ...]
    checked: tuple[Bounds, ...]
    wrap: dict[str, tuple[int, int]]


def signal_info(sig) -> SignalInfo:
    return SignalInfo(sig.name, sig.unit or None, sig.minimum, sig.maximum, sig.scale, sig.offset,
                      sig.length, sig.is_signed, sig.is_float)


def signal_ranges(message: Message) -> SignalRanges:
    """Only signals whose raw bits can leave the DBC range (or floats) saturate on encode and
    are range-checked on decode; counters, CRCs and full-range enums wrap."""
    saturate, checked, wrap = [], [], {}
    for sig in message.signals:
        lo, hi = sig.minimum, sig.maximum
        raw_lo, raw_hi = raw_bounds(sig)
        narrower = (lo is not None and lo > raw_lo) or (hi is not None and hi < raw_hi)
        if sig.is_float or narrower or sig.scale != 1 or sig.offset != 0:
            saturate.append((sig.name, *_encode_bounds(sig, lo, hi)))
        else:
            wrap[sig.name] = (int(raw_lo), 1 << sig.length)
        if sig.is_float or narrower:
            checked.append((sig.name, lo, hi))
    return SignalRanges(tuple(saturate), tuple(checked), wrap)


def raw_bounds(sig) -> tuple[float, float]:
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
    ends = raw_bounds(sig)
    return (ends[0] if lo is None else max(lo, ends[0]), ends[1] if hi is None else min(hi, ends[1]))


def signal_bits(sig, n_bytes: int) -> tuple[str, int, set[tuple[int, int]]] | None:
    """("le"|"be", shift in the payload read as a little/big-endian int, (byte, bit) cells), or
    None when the bits leave an n_bytes payload."""
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


def numeric_conversion(sig):
    """The signal's conversion as decode (without choice strings) and encode use it: a
    NamedSignalConversion (choices) works through its inner numeric conversion."""
    conv = sig.conversion
    inner = getattr(conv, "_conversion", None)  # when this cantools version exposes it
    return inner if conv.choices is not None and inner is not None else conv


def start_value(sig) -> float:
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


def mux_selections(tree: Sequence) -> list[dict[str, int]]:
    """Every combination of multiplexer values the signal tree allows (cascades included), each
    a {multiplexer signal: value} dict, in the database's order."""
    out: list[dict[str, int]] = [{}]
    for node in tree:
        if not isinstance(node, dict):
            continue
        for mux, branches in node.items():
            options: list[dict[str, int]] = []
            for value, sub in branches.items():
                options.extend({mux: value, **rest} for rest in mux_selections(sub))
            out = [{**a, **b} for a in out for b in options] if options else out
    return out


def arxml_e2e(message: Message) -> ArxmlE2E | None:
    e2e = message.autosar.e2e if message.autosar is not None else None
    if e2e is None:
        return None
    return ArxmlE2E(e2e.category, tuple(e2e.data_ids or ()), e2e.payload_length)
