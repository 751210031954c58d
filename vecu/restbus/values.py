"""What a restbus signal carries over time: its start value, or a VALUES.toml source.

    [[value]]
    signal = "ABS_Wheel.WheelSpeed_FL"   # MESSAGE.SIGNAL
    kind = "sine"                         # constant | ramp | sine | square | random_walk | trace
    offset = 50.0                         # the kind's keys (SOURCES below)
    amplitude = 20.0
    period_s = 4.0

Every source is a pure function of the simulated time (random_walk: of its seeded stream and
the sample index), so reruns are byte-identical; every value stays within the signal's DBC
range (a constant outside it is refused; the others are clipped). One entry per kind in
`SOURCES`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vecu.errors import BadFileError

Source = Callable[[float], float]  # value(t_s)


@dataclass(frozen=True)
class SourceKind:
    """One kind of VALUES.toml source: its keys (name -> default, None: required) and builder."""

    keys: dict[str, Any]
    build: Callable[[dict[str, Any], np.random.Generator, Path], Source]
    meaning: str


def _constant(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    v = float(k["value"])
    return lambda t: v


def _ramp(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    start, end, period = float(k["start"]), float(k["end"]), float(k["period_s"])
    if not period > 0:
        raise ValueError("period_s must be > 0")
    period_ns = round(period * 1e9)
    return lambda t: start + (end - start) * ((round(t * 1e9) % period_ns) / period_ns)


def _sine(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    off, amp, period, phase = (float(k[n]) for n in ("offset", "amplitude", "period_s",
                                                       "phase_deg"))
    if not period > 0:
        raise ValueError("period_s must be > 0")
    w, ph = 2 * math.pi / period, math.radians(phase)
    return lambda t: off + amp * math.sin(w * t + ph)


def _square(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    low, high, period, duty = (float(k[n]) for n in ("low", "high", "period_s", "duty"))
    if not period > 0 or not 0 <= duty <= 1:
        raise ValueError("period_s must be > 0 and duty in [0, 1]")
    period_ns, high_ns = round(period * 1e9), round(duty * period * 1e9)  # exact on ns times
    return lambda t: high if round(t * 1e9) % period_ns < high_ns else low


def _random_walk(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    """A step of N(0, step) per sample_s, drawn ahead from the seeded stream as time needs it."""
    start, step, dt = float(k["start"]), float(k["step"]), float(k["sample_s"])
    if not dt > 0 or not step >= 0:
        raise ValueError("sample_s must be > 0 and step >= 0")
    path = [start]

    def value(t: float) -> float:
        i = int(t / dt)
        while len(path) <= i:
            path.append(path[-1] + step * float(rng.standard_normal()))
        return path[i]
    return value


def _trace(k: dict[str, Any], rng: np.random.Generator, base: Path) -> Source:
    """Sample-and-hold of one column of a CSV file against its time column (seconds)."""
    path = Path(k["file"])
    if not path.is_absolute():
        path = base / path
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    col, tcol = str(k["column"]), str(k["time_column"])
    if not rows or col not in rows[0] or tcol not in rows[0]:
        raise ValueError(f"{path} has no columns {tcol!r} and {col!r}")
    try:
        ts = np.array([float(r[tcol]) for r in rows])
        vs = [float(r[col]) for r in rows]
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    if np.any(np.diff(ts) < 0):
        raise ValueError(f"{path}: column {tcol!r} is not in time order")
    repeat = bool(k["repeat"])
    span = float(ts[-1] - ts[0]) if len(ts) > 1 else 0.0

    def value(t: float) -> float:
        if repeat and span > 0:
            t = ts[0] + (t - ts[0]) % span
        i = int(np.searchsorted(ts, t, side="right")) - 1
        return vs[max(i, 0)]
    return value


SOURCES: dict[str, SourceKind] = {
    "constant": SourceKind({"value": None}, _constant, "the value, always"),
    "ramp": SourceKind({"start": None, "end": None, "period_s": None}, _ramp,
                       "start to end over period_s, then again"),
    "sine": SourceKind({"offset": 0.0, "amplitude": None, "period_s": None, "phase_deg": 0.0},
                       _sine, "offset + amplitude sin(2 pi t / period_s + phase)"),
    "square": SourceKind({"low": None, "high": None, "period_s": None, "duty": 0.5}, _square,
                         "high for duty x period_s, then low"),
    "random_walk": SourceKind({"start": None, "step": None, "sample_s": 0.01}, _random_walk,
                              "start + N(0, step) per sample_s (seeded)"),
    "trace": SourceKind({"file": None, "column": None, "time_column": "t", "repeat": False},
                        _trace, "a CSV column against its time column, sample and hold"),
}


@dataclass(frozen=True)
class ValueSpec:
    """One VALUES.toml entry: MESSAGE.SIGNAL, the kind and its keys."""

    message: str
    signal: str
    kind: str
    keys: tuple[tuple[str, Any], ...]


def parse_values(table: Mapping[str, Any], origin: str) -> list[ValueSpec]:
    """The [[value]] entries of a VALUES.toml (already read); errors name `origin` and the entry."""
    entries = table.get("value", [])
    unknown = sorted(set(table) - {"value"})
    if unknown:
        raise BadFileError(origin, f"unknown table {unknown[0]!r} (expected [[value]] entries)")
    if not isinstance(entries, list):
        raise BadFileError(origin, "'value' must be an array of tables ([[value]])")
    out = []
    for i, e in enumerate(entries, 1):
        where = f"[[value]] #{i}"
        target = e.get("signal")
        if not isinstance(target, str) or target.count(".") != 1:
            raise BadFileError(origin, f"{where}: 'signal' must be \"MESSAGE.SIGNAL\"")
        kind = e.get("kind", "constant" if "value" in e else None)
        if kind not in SOURCES:
            raise BadFileError(origin, f"{where} ({target}): unknown kind {kind!r} (known: "
                               f"{', '.join(SOURCES)})")
        keys = dict(SOURCES[kind].keys)
        extra = sorted(set(e) - set(keys) - {"signal", "kind"})
        if extra:
            raise BadFileError(origin, f"{where} ({target}): unknown key {extra[0]!r} for kind "
                               f"{kind} (keys: {', '.join(keys)})")
        for name, default in keys.items():
            if name in e:
                keys[name] = e[name]
            elif default is None:
                raise BadFileError(origin, f"{where} ({target}): kind {kind} needs {name!r}")
        message, signal = target.split(".")
        out.append(ValueSpec(message, signal, kind, tuple(keys.items())))
    return out


def build_source(spec: ValueSpec, lo: float | None, hi: float | None, rng: np.random.Generator,
                 base: Path, origin: str) -> Source:
    """The spec's source, clipped into [lo, hi]; a constant outside it is refused."""
    keys = dict(spec.keys)
    where = f"{spec.message}.{spec.signal}"
    try:
        for name, v in keys.items():
            if name not in ("file", "column", "time_column", "repeat") and not (
                    isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        src = SOURCES[spec.kind].build(keys, rng, base)
    except (ValueError, KeyError, TypeError) as exc:
        raise BadFileError(origin, f"{where} ({spec.kind}): {exc}") from None
    if spec.kind == "constant":
        v = float(keys["value"])
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise BadFileError(origin, f"{where}: value {v:g} is outside the signal's range "
                               f"[{'-inf' if lo is None else f'{lo:g}'}, "
                               f"{'inf' if hi is None else f'{hi:g}'}]")
        return src
    lo_ = -math.inf if lo is None else lo
    hi_ = math.inf if hi is None else hi
    return lambda t: min(max(src(t), lo_), hi_)
