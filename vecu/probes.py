"""Probes: read plant truth and ECU output after each tick, in constant memory (plus optional
series). The mechanics shared by every function's probe; each probe lives with its function's
registry entry (vecu.functions)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE


class Probe(Protocol):
    """Compares one ECU function's output with the plant's truth, every period_ns."""

    period_ns: int

    def tick(self, t_ns: int) -> None: ...

    def series(self) -> Any: ...  # per-sample rows for plots (None: not kept)

    def summary(self) -> Any: ...  # the function's typed section of the run summary


class SeriesBuffer:
    """A probe's per-tick series rows: appended as tuples, written into the preallocated
    (columns x capacity) float array a chunk at a time (one numpy call per CHUNK rows instead
    of one per tick); rows past the capacity are dropped."""

    CHUNK = 1024

    def __init__(self, columns: int, capacity: int) -> None:
        self._array = np.full((columns, capacity), np.nan)
        self._rows: list[tuple[float, ...]] = []
        self._n = 0
        self._room = capacity

    def append(self, row: tuple[float, ...]) -> None:
        if self._room:
            self._room -= 1
            rows = self._rows
            rows.append(row)
            if len(rows) == self.CHUNK:
                self._flush()

    def _flush(self) -> None:
        rows = self._rows
        if rows:
            self._array[:, self._n:self._n + len(rows)] = np.array(rows, dtype=np.float64).T
            self._n += len(rows)
            rows.clear()

    def view(self) -> np.ndarray:
        """(columns, rows so far)"""
        self._flush()
        return self._array[:, :self._n]


def source_name(source: int) -> str:
    """A function's output source code as the summary names it."""
    return "estimate" if source == SOURCE_ESTIMATE else "sensor"
