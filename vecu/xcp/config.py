"""The XCP slave's parameters (`ecu.xcp.*` in the parameter tree; docs/xcp.md)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from vecu.instances import xcp_ids
from vecu.params import ParamError

CAN_ID_BOUNDS = {"bounds": (0, 0x7FF)}


@dataclass(frozen=True)
class XcpConfig:
    enabled: bool = True  # False: the ECU claims no XCP ID
    # instance 0's IDs (vecu.instances: ecu.instance moves them unless they are set)
    master_id: int = field(default=xcp_ids(0)["master_id"],
                           metadata=CAN_ID_BOUNDS)  # CAN_ID_MASTER (commands)
    slave_id: int = field(default=xcp_ids(0)["slave_id"],
                          metadata=CAN_ID_BOUNDS)   # CAN_ID_SLAVE (responses, DAQ)
    # seed & key (GET_SEED / UNLOCK) protects CAL/PAG, DAQ and PGM; off: all unlocked
    seed_key: bool = False
    secret: str = "vecu-xcp"  # the seed & key secret (vecu/xcp/security.py)
    # bounded work per 1 ms tick: commands answered (a flood costs bounded time)
    commands_per_tick: int = field(default=8, metadata={"bounds": (1, 256)})
    # DAQ frames sent per tick at most (beyond: the ODT is lost and counted, OVERLOAD)
    daq_frames_per_tick: int = field(default=64, metadata={"bounds": (1, 4096)})
    max_daq_lists: int = field(default=16, metadata={"bounds": (1, 255)})
    max_odt_entries: int = field(default=2048, metadata={"bounds": (1, 65535)})
    a2l_name: str = "vecu"  # GET_ID type 1: the A2L's file name without extension


def check_xcp(cfg: XcpConfig, uds_ids: set[int]) -> None:
    """The XCP IDs differ from each other and from the UDS server's; the A2L name is an
    identifier (ParamError naming the leaf)."""
    if not cfg.enabled:
        return
    if cfg.master_id == cfg.slave_id:
        raise ParamError(f"parameters 'ecu.xcp.master_id' and 'ecu.xcp.slave_id' must differ, "
                         f"got 0x{cfg.master_id:X} for both")
    for name in ("master_id", "slave_id"):
        value = getattr(cfg, name)
        if value in uds_ids:
            raise ParamError(f"parameter 'ecu.xcp.{name}' = 0x{value:X} clashes with a UDS ID "
                             f"(ecu.uds.*: {', '.join(f'0x{i:X}' for i in sorted(uds_ids))})")
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,63}", cfg.a2l_name):
        raise ParamError(f"parameter 'ecu.xcp.a2l_name': expected an identifier (letters, digits, "
                         f"'_'), got {cfg.a2l_name!r}")
    if not cfg.secret.isascii() or not cfg.secret:
        raise ParamError("parameter 'ecu.xcp.secret': expected a non-empty ASCII string")


@dataclass(frozen=True)
class XcpStep:
    """A scenario's XCP step at `at_s` (docs/xcp.md): write a characteristic (`write` = its A2L
    name, `value`) and/or read a characteristic or measurement (`read`), and what must come:
    `expect` (the value read, within `tolerance`), `expect_min` / `expect_max`, or
    `expect_error` (the XCP error name, e.g. ERR_OUT_OF_RANGE, of the write)."""

    at_s: float
    write: str | None = None
    value: float | None = None
    read: str | None = None
    expect: float | None = None
    tolerance: float = 0.0
    expect_min: float | None = None
    expect_max: float | None = None
    expect_error: str | None = None
