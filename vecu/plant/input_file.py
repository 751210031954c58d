"""The throttle input u(t) from a user's file (`vecu excite throttle --input FILE`): CSV with
columns `t_s`, `u_V` (format: docs/reproduction.md), u linearly interpolated at each 1 ms tick and
held beyond the ends; a file that breaks the format is a BadFileError naming it and the row.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vecu.errors import BadFileError

T_COLUMN, U_COLUMN = "t_s", "u_V"
U_MAX_V = 12.0  # the range of ETB_Voltage in dbc/vecu.dbc: what the wattmeter frame can carry
CHUNK = 1000  # samples interpolated at a time


@dataclass(frozen=True)
class InputSeries:
    """Rows of a u(t) file: times (s, strictly increasing) and voltages (V)."""

    path: str
    t_s: np.ndarray
    u_v: np.ndarray

    @property
    def end_s(self) -> float:
        return float(self.t_s[-1])

    def sample(self, t_s: np.ndarray) -> np.ndarray:
        """u at the times t_s: linear between rows, held outside them."""
        return np.interp(t_s, self.t_s, self.u_v)


def _number(path: str, line: int, column: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise BadFileError(path, f"line {line}: {column} {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise BadFileError(path, f"line {line}: {column} {text.strip()!r} is not finite")
    return value


def load_input_file(path: str | Path) -> InputSeries:
    """Read and check a u(t) file (module docstring); BadFileError on any problem."""
    path = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            lines = [(n, text) for n, text in enumerate(f, start=1)
                     if text.strip() and not text.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise BadFileError(path, f"cannot read the input file: "
                                 f"{getattr(exc, 'strerror', None) or exc}") from None
    if not lines:
        raise BadFileError(path, f"empty: expected a header row with {T_COLUMN},{U_COLUMN} "
                                 "and one row per sample")
    header_line, header_text = lines[0]
    header = [h.strip() for h in next(csv.reader([header_text]))]
    lower = [h.lower() for h in header]
    cols = {}
    for name in (T_COLUMN, U_COLUMN):
        if name.lower() not in lower:
            raise BadFileError(path, f"line {header_line}: no {name} column in the header "
                                     f"({','.join(header)}); expected {T_COLUMN},{U_COLUMN}")
        cols[name] = lower.index(name.lower())
    if len(lines) == 1:
        raise BadFileError(path, "no data rows after the header")
    t = np.empty(len(lines) - 1)
    u = np.empty(len(lines) - 1)
    for k, row in enumerate(csv.reader([text for _, text in lines[1:]])):
        line = lines[k + 1][0]
        if len(row) <= max(cols.values()):
            raise BadFileError(path, f"line {line}: {len(row)} columns, the header has "
                                     f"{len(header)}")
        t[k] = _number(path, line, T_COLUMN, row[cols[T_COLUMN]])
        u[k] = _number(path, line, U_COLUMN, row[cols[U_COLUMN]])
        if k and t[k] <= t[k - 1]:
            raise BadFileError(path, f"line {line}: {T_COLUMN} {t[k]:g} is not after the "
                                     f"previous row's {t[k - 1]:g} (times must increase)")
        if not 0.0 <= u[k] <= U_MAX_V:
            raise BadFileError(path, f"line {line}: {U_COLUMN} {u[k]:g} is outside "
                                     f"0..{U_MAX_V:g} V (the ETB_Voltage range)")
    return InputSeries(path, t, u)


class BufferedInput:
    """The plant's input one sample at a time (next) or many (take), from chunks _refill()
    returns; InputGenerator and FileInput are made of it."""

    _buf: list[float]
    _pos: int

    def _refill(self) -> list[float]:
        raise NotImplementedError

    def next(self) -> float:
        if self._pos >= len(self._buf):
            self._buf = self._refill()
            self._pos = 0
        u = self._buf[self._pos]
        self._pos += 1
        return u

    def take(self, n: int) -> list[float]:
        """The next n samples (as n calls of next() give them)."""
        out: list[float] = []
        while len(out) < n:
            if self._pos >= len(self._buf):
                self._buf = self._refill()
                self._pos = 0
            m = min(n - len(out), len(self._buf) - self._pos)
            out.extend(self._buf[self._pos:self._pos + m])
            self._pos += m
        return out


class FileInput(BufferedInput):
    """The plant's input generator (InputGenerator's next()) playing an InputSeries: the k-th
    call returns u at k ms."""

    def __init__(self, series: InputSeries, fs_hz: float = 1000.0) -> None:
        self.series = series
        self._fs = fs_hz
        self._k0 = 0
        self._buf: list[float] = []
        self._pos = 0

    def _refill(self) -> list[float]:
        k = np.arange(self._k0, self._k0 + CHUNK)
        self._k0 += CHUNK
        return self.series.sample(k / self._fs).tolist()
