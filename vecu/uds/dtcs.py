"""DTCs for UDS: SAE J2012 codes per fault the ECU detects, the ISO 14229-1 status byte driven by
the sensor monitors' lifecycle (vecu/ecu/sensor_monitor.py), snapshots and extended data.

A monitor's confirmed finding (SensorStatus) selects the code: the TPS reading 0 V is RANGE_LOW,
so P0122-00. Status bits (ISO 14229-1 D.2):
bit 0 testFailed: the finding is present now; bit 1 testFailedThisOperationCycle; bit 2
pendingDTC: failed in this or the previous operation cycle (an ECUReset ends a cycle); bit 3
confirmedDTC: set with the finding, cleared when the monitor's DTC heals (ages out, dtc_heal_ms
of health) or by 0x14; bit 4 testNotCompletedSinceLastClear and bit 6
testNotCompletedThisOperationCycle: until the monitor has a frame or a finding; bit 5
testFailedSinceLastClear; bit 7 warningIndicatorRequested: not supported (mask 0x7F).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sized
from dataclasses import dataclass, field

from vecu.clock import NS_PER_S
from vecu.ecu.diagnostics import DtcSpec
from vecu.ecu.sensor_monitor import Dtc, DtcState, SensorMonitor
from vecu.ecu.sensor_monitor import SensorStatus as S

TF, TFTOC, PDTC, CDTC, TNCSLC, TFSLC, TNCTOC, WIR = (1 << i for i in range(8))
AVAILABILITY_MASK = 0x7F
CLEARED = TNCSLC | TNCTOC


# The sensors' DTCs are their functions' (`dtcs()`, vecu.ecu.diagnostics.DtcSpec); the bus DTC
# is the server's own.
BUS_DTC = DtcSpec(0xC00100, "bus", (), "high speed CAN bus: error frames (>= 10 per 100 ms)")


@dataclass
class DtcRecord:
    spec: DtcSpec
    status: int = CLEARED
    occurrences: int = 0                 # testFailed 0 -> 1 since the last clear
    healthy_since_ns: int | None = None  # when the finding last went away
    snapshot: bytes | None = None        # record 0x01: (DID, data)* at the last confirmation
    snapshot_count: int = 0


@dataclass
class _Source:
    """One monitor (or the bus DTC) and what was last seen of it."""

    dtc: Dtc
    monitor: SensorMonitor | None
    records: list[DtcRecord] = field(default_factory=list)
    # the sum of the lengths of its status and DTC histories (both only grow: a new entry in
    # either changes it); -1: evaluate at the next update
    seen: int = -1
    # the monitor's status history (none: empty) and the DTC's history
    histories: tuple[Sized, Sized] = ((), ())

    def __post_init__(self) -> None:
        mon = self.monitor
        self.histories = (() if mon is None else mon.status_history, self.dtc.history)


class DtcMemory:
    """The ECU's DTCs; update(t_ns) once per tick (cheap when nothing changed)."""

    def __init__(self, monitors: dict[str, SensorMonitor], specs: Iterable[DtcSpec], bus_dtc: Dtc,
                 snapshot: Callable[[], tuple[bytes, int]]) -> None:
        """specs: the functions' DTCs (their dtcs()); BUS_DTC is added."""
        table = (*specs, BUS_DTC)
        self._snapshot = snapshot
        self.records: dict[int, DtcRecord] = {}
        self._sources: list[_Source] = []
        for name, dtc in [(n, m.dtc_item) for n, m in monitors.items()] + [("bus", bus_dtc)]:
            src = _Source(dtc, monitors.get(name))
            for spec in table:
                if spec.source == name:
                    rec = DtcRecord(spec)
                    src.records.append(rec)
                    self.records[spec.number] = rec
            self._sources.append(src)
        self.enabled = True   # ControlDTCSetting: off freezes every status bit
        self._incomplete = True

    def update(self, t_ns: int) -> None:
        if not self.enabled:
            return
        for src in self._sources:
            status, dtc = src.histories
            seen = len(status) + len(dtc)
            if seen != src.seen:
                src.seen = seen
                self._evaluate(src, t_ns)
        if self._incomplete:
            self._incomplete = False
            for src in self._sources:
                mon = src.monitor
                done = mon is None or mon.last_rx_ns is not None or mon.status != S.OK
                for rec in src.records:
                    if rec.status & (TNCSLC | TNCTOC):
                        if done:
                            rec.status &= ~(TNCSLC | TNCTOC)
                        else:
                            self._incomplete = True

    def _evaluate(self, src: _Source, t_ns: int) -> None:
        mon = src.monitor
        healed = src.dtc.state == DtcState.HEALED
        for rec in src.records:
            failing = (src.dtc.state == DtcState.CONFIRMED if mon is None
                       else mon.status in rec.spec.findings)
            st = rec.status
            if failing and not st & TF:
                rec.occurrences = min(rec.occurrences + 1, 255)
                rec.healthy_since_ns = None
                st |= TF | TFTOC | PDTC | TFSLC
                st &= ~(TNCSLC | TNCTOC)
                if not st & CDTC:
                    st |= CDTC
                    rec.snapshot, rec.snapshot_count = self._snapshot()
            elif not failing and st & TF:
                st &= ~TF
                rec.healthy_since_ns = t_ns
            if healed and not failing:
                st &= ~CDTC
            rec.status = st

    def clear(self, numbers: list[int], t_ns: int) -> None:
        """0x14: forget these DTCs; a finding still present sets them again at once."""
        for src in self._sources:
            hit = [r for r in src.records if r.spec.number in numbers]
            for rec in hit:
                rec.status, rec.occurrences, rec.snapshot, rec.snapshot_count = CLEARED, 0, None, 0
                rec.healthy_since_ns = None
            if hit and len(hit) == len(src.records):  # the monitor's lifecycle too
                src.dtc.clear(t_ns)
            if hit:
                src.seen = -1
        self._incomplete = True

    def new_operation_cycle(self) -> None:
        """ECUReset: pending keeps only what failed in the cycle that ends."""
        for rec in self.records.values():
            st = rec.status
            st = (st | PDTC) if st & TFTOC else (st & ~PDTC)
            rec.status = (st & ~TFTOC) | TNCTOC
        for src in self._sources:
            src.seen = -1
        self._incomplete = True

    def resume(self) -> None:
        """ControlDTCSetting on: catch up with the monitors."""
        self.enabled = True
        for src in self._sources:
            src.seen = -1

    def aging_counter(self, rec: DtcRecord, t_ns: int) -> int:
        """Whole seconds healthy since the finding went away (0 while failing, max 255)."""
        if rec.status & TF or rec.healthy_since_ns is None:
            return 0
        return min(255, (t_ns - rec.healthy_since_ns) // NS_PER_S)
