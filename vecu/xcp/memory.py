"""The slave's memory map: the calibration segment (every numeric `ecu.*` leaf at a fixed
address, little-endian) with its working and reference pages, the measurement area (the ECU's
variables, read when sampled) and the identification area GET_ID uploads from.

Layout (address extension 0, byte granularity; the A2L says the same):

  0x0001_0000  calibration segment 0: leaves in tree order, each aligned to its size
               float: FLOAT64_IEEE (8 bytes: a written value is the Python float --set parses)
               int: SLONG (4), bool: UBYTE (0/1), vector or table of floats: VAL_BLK of
               FLOAT64_IEEE (a table row after row)
  0x0010_0000  measurements (measurements.py), read-only: FLOAT32_IEEE (a DAQ entry fits a
               CAN DTO, 7 bytes after the PID), UBYTE, ULONG
  0x00F0_0000  GET_ID: the identification GET_ID last put there (text, the A2L), read-only
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from vecu import params as ptree

CAL_BASE = 0x0001_0000
MEAS_BASE = 0x0010_0000
ID_BASE = 0x00F0_0000
ID_SIZE = 0x0010_0000

# struct code, size, A2L datatype, A2L record layout
FLOAT, INT, BOOL = "d", "i", "B"
TYPES: dict[str, tuple[int, str, str]] = {
    FLOAT: (8, "FLOAT64_IEEE", "RL_FLOAT64"), INT: (4, "SLONG", "RL_SLONG"),
    BOOL: (1, "UBYTE", "RL_UBYTE"), "H": (2, "UWORD", "RL_UWORD"),
    "f": (4, "FLOAT32_IEEE", "RL_FLOAT32"),
    "I": (4, "ULONG", "RL_ULONG"),
}


def code_of(value: Any) -> str | None:
    """The struct code of a numeric leaf value (None: not numeric, e.g. a name)."""
    if isinstance(value, bool):
        return BOOL
    if isinstance(value, int):
        return INT
    if isinstance(value, float):
        return FLOAT
    if isinstance(value, tuple) and value and all(type(v) is float for v in value):
        return FLOAT
    if (isinstance(value, tuple) and value and all(isinstance(r, tuple) for r in value)
            and len({len(r) for r in value}) == 1
            and all(type(v) is float for r in value for v in r)):
        return FLOAT  # a table (rows of equal length): a 2-D VAL_BLK
    return None


def dims_of(value: Any) -> tuple[int, ...]:
    """(n,) of a vector, (rows, columns) of a table, () of a number."""
    if not isinstance(value, tuple):
        return ()
    if value and isinstance(value[0], tuple):
        return (len(value), len(value[0]))
    return (len(value),)


@dataclass(frozen=True)
class CalLeaf:
    """One characteristic: its tree path (under `ecu.`), address, element code and count."""

    path: str          # relative to the ecu subtree, e.g. "throttle.tps_monitor.plaus_debounce"
    address: int
    code: str
    count: int         # 1: a VALUE; > 1: a VAL_BLK
    unit: str
    bounds: tuple[float, float]
    writable: bool     # the ECU takes it live (calibration.py); else READ_ONLY
    dims: tuple[int, ...] = ()  # (n,) a vector, (rows, columns) a table, () a number

    @property
    def size(self) -> int:
        return TYPES[self.code][0] * self.count

    @property
    def name(self) -> str:
        return "ecu." + self.path

    def pack(self, value: Any) -> bytes:
        if len(self.dims) == 2:  # row after row
            value = tuple(v for row in value for v in row)
        items = value if isinstance(value, tuple) else (value,)
        return struct.pack(f"<{self.count}{self.code}", *items)

    def unpack(self, data: bytes) -> Any:
        items = struct.unpack(f"<{self.count}{self.code}", data)
        if self.code == BOOL:
            return items[0]  # 0/1: parse_value refuses 2..255 for a bool
        if len(self.dims) == 2:
            cols = self.dims[1]
            return tuple(items[i:i + cols] for i in range(0, self.count, cols))
        return items if self.count > 1 else items[0]


class CalSegment:
    """The calibration segment's layout over an ecu subtree (any tree of frozen dataclasses)."""

    def __init__(self, ecu_tree: Any, writable: Callable[[str], bool]) -> None:
        self.leaves: list[CalLeaf] = []
        offset = 0
        for leaf in ptree.leaves(ecu_tree):
            code = code_of(leaf.value)
            if code is None:
                continue
            elem = TYPES[code][0]
            offset = -(-offset // elem) * elem  # aligned
            dims = dims_of(leaf.value)
            count = math.prod(dims) if dims else 1
            bounds = (0.0, 1.0) if code == BOOL else _bounds(ecu_tree, leaf.path)
            self.leaves.append(CalLeaf(leaf.path, CAL_BASE + offset, code, count, leaf.unit,
                                       bounds, writable(leaf.path), dims))
            offset += elem * count
        self.size = -(-offset // 8) * 8
        self.by_path = {leaf.path: leaf for leaf in self.leaves}

    def image(self, ecu_tree: Any) -> bytearray:
        """The segment's bytes for a tree's values."""
        out = bytearray(self.size)
        for leaf in self.leaves:
            start = leaf.address - CAL_BASE
            out[start:start + leaf.size] = leaf.pack(ptree.get(ecu_tree, leaf.path))
        return out

    def overlapping(self, start: int, end: int) -> list[CalLeaf]:
        """Leaves with a byte in [start, end) (segment offsets)."""
        return [leaf for leaf in self.leaves
                if leaf.address - CAL_BASE < end and start < leaf.address - CAL_BASE + leaf.size]


def _bounds(tree: Any, path: str) -> tuple[float, float]:
    parent, _, name = path.rpartition(".")
    node = ptree.get(tree, parent) if parent else tree
    fld = next(f for f in dataclasses.fields(node) if f.name == name)
    return ptree.bounds_of(path, fld)
