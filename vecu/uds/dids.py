"""Data identifiers (0x22 / 0x2E / 0x2F): the ECU's identification, then the DIDs each function
it runs shows (its `dids()`: live estimates and sensor statuses, a writable calibration, the
sensor values a tester may override). The Did record itself is vecu.ecu.diagnostics'.
docs/uds.md has the table (`did_table()` prints it).
"""

from __future__ import annotations

from collections.abc import Callable

from vecu.ecu.diagnostics import Did, Reader
from vecu.ecu.node import EcuNode
from vecu.uds.config import UdsConfig

SW_VERSION = "vecu-0.1.0-uds1"
__all__ = ["SNAPSHOT_DIDS", "SW_VERSION", "Did", "Reader", "build_dids", "did_table"]


def _ascii(text: str) -> Callable[[], bytes]:
    data = text.encode("ascii", "replace")
    return lambda: data


def fn_dids(fn: object) -> list[Did]:
    """The DIDs a function shows (none when it has no `dids()`)."""
    own = getattr(fn, "dids", None)
    return list(own()) if own is not None else []


def build_dids(node: EcuNode, config: UdsConfig, now_ns: Callable[[], int],
               session: Callable[[], int]) -> dict[int, Did]:
    """Every DID of this ECU: identification, then one group per function it runs."""
    dids = [
        Did(0xF190, "VIN", f"{len(config.vin)}s", 1, "ASCII", _ascii(config.vin)),
        Did(0xF195, "software version", f"{len(SW_VERSION)}s", 1, "ASCII", _ascii(SW_VERSION)),
        Did(0xF18C, "ECU serial number", f"{len(config.serial)}s", 1, "ASCII",
            _ascii(config.serial)),
        Did(0xF186, "active diagnostic session", "B", 1, "", lambda: float(session())),
        Did(0x0001, "ECU time since start", "I", 1, "ms", lambda: now_ns() // 1_000_000),
        # the host's doing, not a sensor's (a live bus): in a DTC's snapshot they tell a
        # stalled ECU or sender from a silent sensor
        Did(0x0002, "ECU not running since start (skipped base ticks)", "I", 1, "ms",
            lambda: node.host.stalled_ns // 1_000_000),
        Did(0x0003, "sensor frames' sender: ticks its host skipped (PLANT_Host)", "H", 1, "",
            lambda: float(node.host.sender_skipped)),
        Did(0x0004, "sensor frames' sender: ticks its host delayed (PLANT_Host)", "H", 1, "",
            lambda: float(node.host.sender_late)),
    ]
    for fn in node.functions:  # one group per function the node runs (its own list)
        dids += fn_dids(fn)
    return {d.did: d for d in dids}


# the freeze frame stored with a DTC at confirmation (those of them the ECU has)
SNAPSHOT_DIDS = (0x0001, 0x0002, 0x0003, 0x0004, 0x0100, 0x0101, 0x0104, 0x0105, 0x0300,
                 0x0400, 0x0403)


def did_table(dids: dict[int, Did]) -> str:
    """The DIDs as a Markdown table (docs/uds.md)."""
    rows = ["| DID | name | bytes | encoding | unit | access |", "|---|---|---|---|---|---|"]
    for d in sorted(dids.values(), key=lambda d: d.did):
        enc = "ASCII" if d.fmt.endswith("s") else (
            f"{'signed' if d.fmt.islower() else 'unsigned'} x {d.scale:g}")
        access = "read" + (", write (0x2E)" if d.write else "") + (
            f", IO control (0x2F: {d.io[0]}.{d.io[1]})" if d.io else "")
        rows.append(f"| 0x{d.did:04X} | {d.name} | {d.size} | {enc} | {d.unit} | {access} |")
    return "\n".join(rows)
