"""A replay diffed against its recording: every frame the replayed ECU sends against the frame of
the same ID the trace recorded at the same time, signal by signal, with a verdict.

- Pairing: per message, each replayed frame with the nearest recorded frame of its ID within half
  the message's cycle (DBC GenMsgCycleTime; event messages: EVENT_WINDOW_NS), each recorded frame
  used once; the others are counted as recorded-only / replayed-only.
- Signals: decoded with vecu.codec (DBC units), difference replayed - recorded: max |d|, RMS, the
  share of pairs with |d| above the signal's tolerance, the first such time (trace time, s).
- E2E: a message's CRC and alive counter (AUTOSAR E2E P11, vecu.codec.E2ELayout) are protocol,
  not numbers: every frame's CRC checked (autosar-e2e) and each counter against the previous
  frame's + 1 (mod the profile's range), for the replay and for the recording; the replay must
  have no error.
- Verdict: "pass" when every signal's share outside its tolerance is at most `max_share`, the
  unpaired frames at most `max_unmatched` and the replay's E2E clean; "fail" otherwise; "none"
  when the trace holds no frame of the ECU's messages (nothing to diff against).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from vecu.can_message import Values
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec, FrameCodec
from vecu.errors import BadFileError
from vecu.replay.source import TraceSource
from vecu.tomlfile import read_toml

ECU_NODE = "VECU"  # the DBC node whose messages the replayed ECU sends
EVENT_WINDOW_NS = NS_PER_MS // 2  # pairing window of a message without a cycle time
DEFAULT_LSB = 1.0  # default tolerance: this many steps of the signal's DBC scale
KEYS: dict[str, type | tuple[type, ...]] = {
    "lsb": (int, float), "max_share": (int, float), "max_unmatched": int, "ignore": list,
    "tolerance": dict}


class DiffFileError(BadFileError):
    """A bad DIFF.toml: DiffFileError(path, problem naming the key)."""


@dataclass(frozen=True)
class DiffSpec:
    """Tolerances (DIFF.toml; docs/replay.md 'Fleet'): per signal an absolute tolerance in the
    DBC's unit ("Message.Signal" or "Signal"), else `lsb` steps of the signal's scale."""

    path: str | None = None
    lsb: float = DEFAULT_LSB
    max_share: float = 0.0      # share of a signal's pairs allowed outside its tolerance
    max_unmatched: int = 0      # recorded-only + replayed-only frames allowed per trace
    ignore: tuple[str, ...] = ()  # messages or Message.Signal not compared
    tolerance: tuple[tuple[str, float], ...] = ()

    def tolerance_of(self, message: str, signal: str, scale: float) -> float:
        tol = dict(self.tolerance)
        for key in (f"{message}.{signal}", signal):
            if key in tol:
                return tol[key]
        return self.lsb * abs(scale)

    def ignored(self, message: str, signal: str | None = None) -> bool:
        return message in self.ignore or (signal is not None and (
            f"{message}.{signal}" in self.ignore or signal in self.ignore))


def load_diff_spec(path: str | None) -> DiffSpec:
    """DIFF.toml (None: the defaults); every problem one error naming the file and key."""
    if path is None:
        return DiffSpec()
    data = read_toml(path, DiffFileError)
    for key, value in data.items():
        if key not in KEYS:
            raise DiffFileError(path, f"unknown key {key!r} (known: {', '.join(KEYS)})")
        if not isinstance(value, KEYS[key]) or isinstance(value, bool):
            raise DiffFileError(path, f"{key}: wrong type {type(value).__name__}")
    tol = []
    for name, value in data.get("tolerance", {}).items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
            raise DiffFileError(path, f"tolerance.{name}: expected a number >= 0, got {value!r}")
        tol.append((str(name), float(value)))
    share = float(data.get("max_share", 0.0))
    if not 0.0 <= share <= 1.0:
        raise DiffFileError(path, f"max_share: expected 0..1, got {share}")
    lsb = float(data.get("lsb", DEFAULT_LSB))
    if not (math.isfinite(lsb) and lsb >= 0):
        raise DiffFileError(path, f"lsb: expected a number >= 0, got {lsb}")
    if data.get("max_unmatched", 0) < 0:
        raise DiffFileError(path, "max_unmatched: expected >= 0")
    if not all(isinstance(x, str) for x in data.get("ignore", [])):
        raise DiffFileError(path, "ignore: expected a list of message or Message.Signal names")
    return DiffSpec(str(path), lsb, share, int(data.get("max_unmatched", 0)),
                    tuple(data.get("ignore", [])), tuple(tol))


@dataclass(frozen=True)
class SignalDiff:
    pairs: int
    max_abs: float
    rms: float
    tolerance: float
    outside: int
    share_outside: float
    first_divergence_s: float | None
    passed: bool


@dataclass(frozen=True)
class MessageDiff:
    recorded: int
    replayed: int
    paired: int
    recorded_only: int
    replayed_only: int


@dataclass(frozen=True)
class E2EDiff:
    replayed_crc_errors: int
    replayed_counter_errors: int
    recorded_crc_errors: int
    recorded_counter_errors: int
    passed: bool


@dataclass(frozen=True)
class DiffReport:
    verdict: str  # pass / fail / none
    reasons: list[str]
    spec: str | None
    paired: int
    recorded_only: int
    replayed_only: int
    first_divergence_s: float | None
    messages: dict[str, MessageDiff]
    signals: dict[str, SignalDiff]
    e2e: dict[str, E2EDiff]

    @property
    def failed_signals(self) -> list[str]:
        return [k for k, s in self.signals.items() if not s.passed]


class _Frames:
    """One message's frames: times (ns, replay time base) and payloads."""

    __slots__ = ("t", "data")

    def __init__(self) -> None:
        self.t: list[int] = []
        self.data: list[bytes] = []


class RecordingDiff:
    """Collects the replayed ECU's frames (on_estimate, as the replay sends them), reads the
    recording's frames of the same messages (read_recording) and compares (report)."""

    def __init__(self, codec: DbcCodec, spec: DiffSpec) -> None:
        self.spec = spec
        self.codecs: dict[tuple[int, bool], FrameCodec] = {
            key: codec.by_id[key] for key in sorted(codec.sent_by(ECU_NODE))
            if not spec.ignored(codec.by_id[key].name)}
        self.replayed = {key: _Frames() for key in self.codecs}
        self.recorded = {key: _Frames() for key in self.codecs}
        self._skipped: TraceSource | None = None

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        frames = self.replayed.get((msg.arbitration_id, msg.is_extended_id))
        if frames is not None:
            frames.t.append(t_ns)
            frames.data.append(bytes(msg.data))

    def read_recording(self, trace: str, fmt: str | None, idle_gap_ns: int) -> None:
        """The trace's frames of the ECU's messages, on the replay's time base (the same
        TraceSource ordering, rounding and idle gaps as the replay's). A read error ends the
        reading; the replay reports it."""
        source = TraceSource(trace, fmt, idle_gap_ns=idle_gap_ns)
        for chunk in source.chunks(2048):
            for t_ns, msg in chunk:
                frames = self.recorded.get((msg.arbitration_id, msg.is_extended_id))
                if frames is not None and not msg.is_error_frame and not msg.is_remote_frame:
                    frames.t.append(t_ns)
                    frames.data.append(bytes(msg.data))
        self._skipped = source

    def _trace_s(self, t_ns: int) -> float:
        skipped = self._skipped.skipped_before(t_ns) if self._skipped is not None else 0
        return round((t_ns + skipped) / NS_PER_S, 6)

    def report(self) -> DiffReport:
        spec = self.spec
        messages: dict[str, MessageDiff] = {}
        signals: dict[str, SignalDiff] = {}
        e2e: dict[str, E2EDiff] = {}
        recorded_any = any(f.t for f in self.recorded.values())
        for key, fc in self.codecs.items():
            rep, rec = self.replayed[key], self.recorded[key]
            if not rep.t and not rec.t:
                continue
            window = (fc.cycle_time_ms * NS_PER_MS // 2 if fc.cycle_time_ms
                      else EVENT_WINDOW_NS)
            ri, ci = _pair(np.asarray(rep.t, dtype=np.int64), np.asarray(rec.t, dtype=np.int64),
                           window)
            messages[fc.name] = MessageDiff(len(rec.t), len(rep.t), len(ri), len(rec.t) - len(ri),
                                            len(rep.t) - len(ri))
            if fc.e2e is not None:
                e2e[fc.name] = _e2e(fc, rep.data, rec.data)
            if not len(ri):
                continue
            signals.update(self._signals(fc, rep, rec, ri, ci))
        paired = sum(m.paired for m in messages.values())
        rec_only = sum(m.recorded_only for m in messages.values())
        rep_only = sum(m.replayed_only for m in messages.values())
        firsts = [s.first_divergence_s for s in signals.values()
                  if s.first_divergence_s is not None and not s.passed]
        reasons: list[str] = []
        if not recorded_any:
            verdict = "none"
            reasons.append("the trace holds no frame of the ECU's messages")
        else:
            bad = [k for k, s in signals.items() if not s.passed]
            if bad:
                reasons.append(f"{len(bad)} signals outside tolerance: {', '.join(bad[:8])}"
                               + (" ..." if len(bad) > 8 else ""))
            if rec_only + rep_only > spec.max_unmatched:
                reasons.append(f"{rec_only} frames recorded and not replayed, {rep_only} "
                               f"replayed and not recorded (allowed {spec.max_unmatched})")
            reasons += [f"{name}: replayed E2E errors (CRC {e.replayed_crc_errors}, counter "
                        f"{e.replayed_counter_errors})" for name, e in e2e.items() if not e.passed]
            verdict = "fail" if reasons else "pass"
        return DiffReport(verdict, reasons, spec.path, paired, rec_only, rep_only,
                          min(firsts) if firsts else None, messages, signals, e2e)

    def _signals(self, fc: FrameCodec, rep: _Frames, rec: _Frames, ri: np.ndarray,
                 ci: np.ndarray) -> dict[str, SignalDiff]:
        skip = {fc.e2e.crc_signal, fc.e2e.counter_signal} if fc.e2e is not None else set()
        names = [s.name for s in fc.signals if s.name not in skip
                 and not self.spec.ignored(fc.name, s.name)]
        a = _decode(fc, [rep.data[i] for i in ri], names)
        b = _decode(fc, [rec.data[i] for i in ci], names)
        t = np.asarray(rep.t, dtype=np.int64)[ri]
        out = {}
        scale = {s.name: s.scale for s in fc.signals}
        for j, name in enumerate(names):
            d = a[:, j] - b[:, j]
            same_nan = np.isnan(a[:, j]) & np.isnan(b[:, j])
            d[same_nan] = 0.0
            tol = self.spec.tolerance_of(fc.name, name, scale[name])
            # a difference within rounding of the tolerance is inside it
            outside = ~(np.abs(d) <= tol + 1e-9 * max(abs(scale[name]), 1e-12))
            n_out = int(outside.sum())
            finite = np.abs(d[np.isfinite(d)])
            share = n_out / len(d)
            first = self._trace_s(int(t[np.argmax(outside)])) if n_out else None
            out[f"{fc.name}.{name}"] = SignalDiff(
                len(d), float(finite.max()) if finite.size else math.nan,
                float(np.sqrt(np.mean(finite ** 2))) if finite.size else math.nan, tol, n_out,
                round(share, 6), first, share <= self.spec.max_share)
        return out


def _pair(rt: np.ndarray, ct: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (replayed, recorded) of the pairs: each replayed time with the nearest recorded
    time within `window` ns, each recorded time taken once (by the first replayed frame)."""
    if not len(rt) or not len(ct):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    hi = np.clip(np.searchsorted(ct, rt), 0, len(ct) - 1)
    lo = np.clip(hi - 1, 0, len(ct) - 1)
    nearest = np.where(np.abs(ct[lo] - rt) <= np.abs(ct[hi] - rt), lo, hi)
    ok = np.abs(ct[nearest] - rt) <= window
    ri = np.flatnonzero(ok)
    ci = nearest[ok]
    _, first = np.unique(ci, return_index=True)
    keep = np.sort(first)
    return ri[keep], ci[keep]


def _decode(fc: FrameCodec, payloads: list[bytes], names: list[str]) -> np.ndarray:
    """Rows of decoded values (vecu.codec: all at once when every payload has the message's
    length and the message a block layout, else frame by frame), NaN where a payload does not
    decode."""
    if payloads and all(len(p) == fc.length for p in payloads):
        block = fc.check_block(list(payloads))
        if block is not None:
            col = {n: i for i, n in enumerate(block.names)}
            return np.array([block.columns[col[n]] for n in names], dtype=float).T.reshape(
                len(payloads), len(names))
    out = np.full((len(payloads), len(names)), np.nan)
    for i, data in enumerate(payloads):
        try:
            values = fc.decode(data)
        except Exception:  # noqa: BLE001, S112 - a frame that does not decode: NaN, unlike any value
            continue
        out[i] = [float(values[n]) for n in names]
    return out


def _e2e_errors(fc: FrameCodec, payloads: list[bytes]) -> tuple[int, int]:
    """(CRC errors, counter errors) of a message's frames in order (AUTOSAR E2E: a counter is
    the previous one + 1 modulo the profile's range)."""
    assert fc.e2e is not None
    prot = fc.e2e.protection
    modulo = prot.counter_modulo
    crc = counter = 0
    previous: int | None = None
    for data in payloads:
        if not fc.crc_ok(data):
            crc += 1
        try:
            c = prot.counter(data)
        except IndexError:
            counter += 1
            continue
        if previous is not None and c != (previous + 1) % modulo:
            counter += 1
        previous = c
    return crc, counter


def _e2e(fc: FrameCodec, replayed: list[bytes], recorded: list[bytes]) -> E2EDiff:
    rc, rn = _e2e_errors(fc, replayed)
    cc, cn = _e2e_errors(fc, recorded)
    return E2EDiff(rc, rn, cc, cn, rc == 0 and rn == 0)


def describe(report: DiffReport) -> str:
    """One line: the verdict and why."""
    head = f"diff {report.verdict}: {report.paired} frames paired"
    if report.reasons:
        return head + "; " + "; ".join(report.reasons)
    return head


def as_row(report: DiffReport | None) -> dict[str, Any]:
    if report is None:
        return {}
    return {"diff": report.verdict, "diff_paired": report.paired,
            "diff_recorded_only": report.recorded_only,
            "diff_replayed_only": report.replayed_only,
            "diff_failed_signals": " ".join(report.failed_signals),
            "diff_first_divergence_s": report.first_divergence_s}


__all__ = ["DiffReport", "DiffSpec", "RecordingDiff", "as_row", "describe", "load_diff_spec"]
