"""The A2L (ASAM MCD-2 MC 1.7.1) that describes the XCP slave: the calibration segment's
CHARACTERISTICs (every numeric `ecu.*` leaf: VALUE, or VAL_BLK for a vector or a table), the ECU's
MEASUREMENTs, one COMPU_METHOD per unit, and IF_DATA XCP (protocol layer, the calibration
segment's two pages, DAQ with its event channels, XCP on CAN with the tree's IDs).

Names are the tree's dotted paths (`ecu.throttle.tps_monitor.plaus_debounce`) and the
measurement names (`throttle.estimate_deg`); the long identifier is the leaf's source (or the
measurement's meaning). A leaf the running ECU cannot take (its function's calibrations()) is READ_ONLY.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Any

from vecu import params as ptree
from vecu.xcp.config import XcpConfig
from vecu.xcp.daq import EVENTS, MAX_DTO
from vecu.xcp.measurements import Measurement
from vecu.xcp.memory import CAL_BASE, TYPES, CalSegment

ASAP2_VERSION = "1 71"
BAUDRATE = 500_000
TIMEOUTS_MS = (1000, 1000, 1000, 1000, 1000, 1000, 1000)  # T1..T7 (the slave answers in 1 tick)
OPTIONAL_CMDS = (
    "GET_COMM_MODE_INFO", "GET_ID", "GET_SEED", "UNLOCK", "SET_MTA", "UPLOAD", "SHORT_UPLOAD",
    "BUILD_CHECKSUM", "DOWNLOAD", "DOWNLOAD_NEXT", "DOWNLOAD_MAX", "SET_CAL_PAGE",
    "GET_CAL_PAGE", "COPY_CAL_PAGE", "GET_PAG_PROCESSOR_INFO", "GET_SEGMENT_INFO",
    "GET_PAGE_INFO", "CLEAR_DAQ_LIST", "GET_DAQ_LIST_INFO", "GET_DAQ_CLOCK", "GET_DAQ_PROCESSOR_INFO",
    "GET_DAQ_RESOLUTION_INFO", "GET_DAQ_EVENT_INFO", "GET_DAQ_LIST_MODE", "FREE_DAQ",
    "ALLOC_DAQ", "ALLOC_ODT", "ALLOC_ODT_ENTRY",
)


def _text(s: str) -> str:
    """An A2L string literal."""
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _num(x: float) -> str:
    return repr(float(x)) if not float(x).is_integer() else str(int(x))


def compu_method_names(units: Iterable[str]) -> dict[str, str]:
    """One COMPU_METHOD per unit: CM_ and the unit with other characters as '_' (a number
    appended where two units would give the same name, e.g. m/s^2 and (m/s)^2)."""
    names: dict[str, str] = {}
    taken: set[str] = set()
    for unit in sorted(set(units)):
        base = "CM_" + (re.sub(r"[^A-Za-z0-9]+", "_", unit).strip("_") or "none")
        name, n = base, 1
        while name in taken:
            n += 1
            name = f"{base}_{n}"
        taken.add(name)
        names[unit] = name
    return names


def _compu_methods(names: dict[str, str]) -> list[str]:
    return [f'    /begin COMPU_METHOD {name} {_text(unit)}\n'
            f'      IDENTICAL "%.9" {_text(unit)}\n    /end COMPU_METHOD'
            for unit, name in names.items()]


def _record_layouts() -> list[str]:
    return [f"    /begin RECORD_LAYOUT {rl}\n      FNC_VALUES 1 {dtype} ROW_DIR DIRECT\n"
            f"    /end RECORD_LAYOUT" for _, dtype, rl in TYPES.values()]


def _characteristics(segment: CalSegment, tree: Any, cm: dict[str, str]) -> list[str]:
    out = []
    sources = {leaf.path[len("ecu."):]: leaf.source for leaf in ptree.leaves(tree, "ecu.")}
    for leaf in segment.leaves:
        rl = TYPES[leaf.code][2]
        lo, hi = leaf.bounds
        kind = "VALUE" if leaf.count == 1 else "VAL_BLK"
        lines = [f"    /begin CHARACTERISTIC {leaf.name} {_text(sources.get(leaf.path, ''))}",
                 (f"      {kind} 0x{leaf.address:X} {rl} 0 {cm[leaf.unit]} "
                  f"{_num(lo)} {_num(hi)}")]
        if len(leaf.dims) == 2:  # a table, row after row: x = columns, y = rows
            lines.append(f"      MATRIX_DIM {leaf.dims[1]} {leaf.dims[0]} 1")
        elif leaf.count > 1:
            lines.append(f"      MATRIX_DIM {leaf.count} 1 1")
        if not leaf.writable:
            lines.append("      READ_ONLY")
        lines.append("    /end CHARACTERISTIC")
        out.append("\n".join(lines))
    return out


def _measurements(measurements: list[Measurement], cm: dict[str, str]) -> list[str]:
    out = []
    for m in measurements:
        dtype = TYPES[m.code][1]
        out.append(f"    /begin MEASUREMENT {m.name} {_text(m.doc)}\n"
                   f"      {dtype} {cm[m.unit]} 0 0 {_num(m.lo)} {_num(m.hi)}\n"
                   f"      ECU_ADDRESS 0x{m.address:X}\n    /end MEASUREMENT")
    return out


def _groups(segment: CalSegment, measurements: list[Measurement]) -> list[str]:
    """One GROUP per function (its characteristics and measurements), for the tools' trees."""
    groups: dict[str, tuple[list[str], list[str]]] = {}
    for leaf in segment.leaves:
        groups.setdefault(leaf.path.split(".")[0], ([], []))[0].append(leaf.name)
    for m in measurements:
        groups.setdefault(m.name.split(".")[0], ([], []))[1].append(m.name)
    out = []
    for name, (chars, meas) in groups.items():
        body = f"    /begin GROUP {name} {_text('vecu ' + name)}\n      ROOT\n"
        if chars:
            body += "      /begin REF_CHARACTERISTIC\n        " + "\n        ".join(chars) \
                    + "\n      /end REF_CHARACTERISTIC\n"
        if meas:
            body += "      /begin REF_MEASUREMENT\n        " + "\n        ".join(meas) \
                    + "\n      /end REF_MEASUREMENT\n"
        out.append(body + "    /end GROUP")
    return out


def _if_data(cfg: XcpConfig) -> str:
    t = " ".join(str(x) for x in TIMEOUTS_MS)
    events = "\n".join(
        f'          /begin EVENT {_text(ev.name)} {_text(ev.name)} {i} DAQ 0xFF {ev.cycle} '
        f'{ev.unit} {ev.priority}\n          /end EVENT' for i, ev in enumerate(EVENTS))
    cmds = "\n".join(f"          OPTIONAL_CMD {c}" for c in OPTIONAL_CMDS)
    return f"""    /begin IF_DATA XCP
      /begin PROTOCOL_LAYER
        0x0100 {t} {MAX_DTO} {MAX_DTO} BYTE_ORDER_MSB_LAST ADDRESS_GRANULARITY_BYTE
{cmds}
          COMMUNICATION_MODE_SUPPORTED BLOCK SLAVE MASTER 36 0
      /end PROTOCOL_LAYER
      /begin DAQ
        DYNAMIC {cfg.max_daq_lists} {len(EVENTS)} 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE
        IDENTIFICATION_FIELD_TYPE_ABSOLUTE GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE {MAX_DTO - 1}
        NO_OVERLOAD_INDICATION
          PRESCALER_SUPPORTED
          /begin TIMESTAMP_SUPPORTED
            0x1 SIZE_DWORD UNIT_1US
          /end TIMESTAMP_SUPPORTED
{events}
      /end DAQ
      /begin PAG
        0x1 FREEZE_NOT_SUPPORTED
      /end PAG
      /begin XCP_ON_CAN
        0x0100
        CAN_ID_MASTER 0x{cfg.master_id:X}
        CAN_ID_SLAVE 0x{cfg.slave_id:X}
        BAUDRATE {BAUDRATE}
        SAMPLE_POINT 0x4B
        SAMPLE_RATE SINGLE
        BTL_CYCLES 0x8
        SJW 0x2
        SYNC_EDGE SINGLE
      /end XCP_ON_CAN
    /end IF_DATA"""


def _segment_if_data(segment: CalSegment) -> str:
    return f"""      /begin MEMORY_SEGMENT calibration "ecu.* calibration (page 0 working, 1 reference)"
        DATA FLASH INTERN 0x{CAL_BASE:X} 0x{segment.size:X} -1 -1 -1 -1 -1
        /begin IF_DATA XCP
          /begin SEGMENT
            0 2 0 0 0
            /begin CHECKSUM
              XCP_CRC_32 MAX_BLOCK_SIZE 0xFFFF
            /end CHECKSUM
            /begin PAGE
              0x0 ECU_ACCESS_DONT_CARE XCP_READ_ACCESS_DONT_CARE XCP_WRITE_ACCESS_DONT_CARE
            /end PAGE
            /begin PAGE
              0x1 ECU_ACCESS_DONT_CARE XCP_READ_ACCESS_DONT_CARE XCP_WRITE_ACCESS_NOT_ALLOWED
            /end PAGE
          /end SEGMENT
        /end IF_DATA
      /end MEMORY_SEGMENT"""


def render_a2l(cfg: XcpConfig, segment: CalSegment, measurements: list[Measurement],
               tree: Any) -> str:
    """The A2L text for this slave (tree: the ecu subtree the segment was laid out from)."""
    cm = compu_method_names([leaf.unit for leaf in segment.leaves]
                            + [m.unit for m in measurements])
    body = "\n".join([
        *_compu_methods(cm), *_record_layouts(), *_characteristics(segment, tree, cm),
        *_measurements(measurements, cm), *_groups(segment, measurements)])
    name = cfg.a2l_name
    return f"""ASAP2_VERSION {ASAP2_VERSION}
/begin PROJECT {name} "vecu virtual ECU: XCP on CAN (docs/xcp.md)"
  /begin HEADER "generated by vecu a2l from the parameter tree"
    VERSION "1"
  /end HEADER
  /begin MODULE {name} "the virtual ECU"
    /begin MOD_COMMON "vecu"
      BYTE_ORDER MSB_LAST
      ALIGNMENT_BYTE 1
      ALIGNMENT_WORD 2
      ALIGNMENT_LONG 4
      ALIGNMENT_FLOAT32_IEEE 4
      ALIGNMENT_FLOAT64_IEEE 8
    /end MOD_COMMON
    /begin MOD_PAR "vecu"
{_segment_if_data(segment)}
    /end MOD_PAR
{_if_data(cfg)}
{body}
  /end MODULE
/end PROJECT
"""
