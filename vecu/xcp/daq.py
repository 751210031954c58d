"""Dynamic DAQ: lists, ODTs and entries allocated by the master, sampled on the ECU's events.

Event channels (GET_DAQ_EVENT_INFO, the A2L's EVENTs): 0 "1ms", 1 "2ms", 2 "10ms", 3 "100ms"
(cyclic on the ECU's tick) and 4 "engine" (each engine event the manifold function filtered).
A list is sampled at the end of the ECU's tick, after the functions ran (the values of that
tick). DTOs: absolute ODT number as PID (1 byte), then, in the first ODT of a list with
timestamps, the ECU's clock in µs (4 bytes, fixed), then the entries' bytes. At most
`daq_frames_per_tick` DTOs leave per tick; one more is lost and counted (`odts_lost`), never
delaying the broadcast; an entry whose read raises drops its DTO (`odts_dropped`, the slave's
boundary), never raising out of the tick.

XCP 1.5 DAQ rules kept: allocation in the order FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY
(else ERR_SEQUENCE), ALLOC_ODT_ENTRY again on an ODT replaces its entries (and its share of
`max_odt_entries`); a running or selected list keeps its layout and mode (ERR_DAQ_ACTIVE);
CLEAR_DAQ_LIST stops the list, and `running` (GET_STATUS) is recomputed.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from vecu.clock import NS_PER_MS
from vecu.xcp.config import XcpConfig

ERR_DAQ_ACTIVE, ERR_CMD_SYNTAX, ERR_OUT_OF_RANGE = 0x11, 0x21, 0x22
ERR_MODE_NOT_VALID, ERR_SEQUENCE, ERR_DAQ_CONFIG, ERR_MEMORY_OVERFLOW = 0x27, 0x29, 0x2A, 0x30
MAX_DTO = 8
MAX_PID = 0xFB           # PIDs 0..0xFB are DTOs (0xFC.. are responses, events, errors)
TS_SIZE = 4
TIMESTAMP_MODE = 0x34    # unit 1 µs (3 << 4), not fixed (lists choose), 4 bytes (0b100)
TIMESTAMP_NS = 1000
MODE_TIMESTAMP, MODE_STIM, MODE_DTO_CTR, MODE_PID_OFF = 0x10, 0x02, 0x08, 0x20


@dataclass(frozen=True)
class EventChannel:
    name: str
    period_ns: int          # 0: not cyclic (engine events)
    cycle: int              # GET_DAQ_EVENT_INFO / A2L: time cycle and unit (6 = 1 ms)
    unit: int
    priority: int


EVENTS: tuple[EventChannel, ...] = (
    EventChannel("1ms", NS_PER_MS, 1, 6, 0), EventChannel("2ms", 2 * NS_PER_MS, 2, 6, 1),
    EventChannel("10ms", 10 * NS_PER_MS, 10, 6, 2),
    EventChannel("100ms", 100 * NS_PER_MS, 100, 6, 3), EventChannel("engine", 0, 0, 0, 4),
)
ENGINE = 4


class DaqError(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


@dataclass
class DaqList:
    odts: list[list[tuple[int, int, int]]] = field(default_factory=list)  # (addr, size, ext)
    mode: int = 0
    event: int | None = None
    prescaler: int = 1
    priority: int = 0
    selected: bool = False
    running: bool = False
    first_pid: int = 0
    events_seen: int = 0  # events since the last sample (the prescaler)
    compiled: list[list[Callable[[], bytes]]] = field(default_factory=list)


@dataclass
class DaqStats:
    samples: int = 0        # list samples (one per event that fired the list)
    odts_sent: int = 0
    odts_lost: int = 0
    odts_dropped: int = 0   # an entry could not be read: the DTO is not sent (boundary)


class Daq:
    """The DAQ processor. `reader(address, size, ext) -> () -> bytes` compiles an entry (raises
    the command processor's error for an address it cannot read); `send` puts a DTO on the bus
    and returns whether it went."""

    def __init__(self, cfg: XcpConfig) -> None:
        self.cfg = cfg
        self.lists: list[DaqList] = []
        self.stats = DaqStats()
        self.reader: Callable[[int, int, int], Callable[[], bytes]] | None = None
        # an entry's read that raised (the slave's boundary: counted, logged once per kind)
        self.on_read_error: Callable[[Exception], None] | None = None
        self.on_event_name: Callable[[bytes], None] | None = None
        self._state = "free"  # free -> daq -> odt -> entry (the allocation sequence)
        self._ptr: tuple[int, int, int] | None = None
        self._entries = 0
        self.running = False
        self.t_ns = 0  # the command's tick (GET_DAQ_CLOCK)

    def commands(self) -> dict[int, Callable[[bytes], bytes]]:
        return {0xE3: self._clear_list, 0xE2: self._set_ptr, 0xE1: self._write, 0xE0: self._set_mode,
                0xDF: self._get_mode, 0xDE: self._start_stop_list, 0xDD: self._start_stop_synch,
                0xDC: self._clock, 0xDA: self._processor_info, 0xD9: self._resolution_info,
                0xD7: self._event_info, 0xD8: self._list_info, 0xD6: self._free, 0xD5: self._alloc_daq,
                0xD4: self._alloc_odt, 0xD3: self._alloc_entry}

    @staticmethod
    def _need(cto: bytes, n: int) -> None:
        if len(cto) < n:
            raise DaqError(ERR_CMD_SYNTAX)

    def _list(self, cto: bytes, at: int = 2) -> DaqList:
        number = struct.unpack_from("<H", cto, at)[0]
        if number >= len(self.lists):
            raise DaqError(ERR_OUT_OF_RANGE)
        return self.lists[number]

    # ------------------------------------------------------------- info
    def _processor_info(self, cto: bytes) -> bytes:
        # dynamic, prescaler, timestamps; no overload indication; abs. ODT number, ext free
        props = 0x01 | 0x02 | 0x10
        return struct.pack("<BHHBB", props, self.cfg.max_daq_lists, len(EVENTS), 0, 0x00)

    def _resolution_info(self, cto: bytes) -> bytes:
        return struct.pack("<BBBBBH", 1, MAX_DTO - 1, 1, 0, TIMESTAMP_MODE, 1)

    def _event_info(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        number = struct.unpack_from("<H", cto, 2)[0]
        if number >= len(EVENTS):
            raise DaqError(ERR_OUT_OF_RANGE)
        ev = EVENTS[number]
        if self.on_event_name is not None:
            self.on_event_name(ev.name.encode("ascii"))
        return struct.pack("<BBBBBB", 0x04, 0xFF, len(ev.name), ev.cycle, ev.unit, ev.priority)

    def _list_info(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        dl = self._list(cto)
        # dynamic DAQ list (not predefined, event not fixed), DAQ direction only
        return struct.pack("<BBBH", 0x04, len(dl.odts), max((len(o) for o in dl.odts), default=0),
                           0)

    def _clock(self, cto: bytes) -> bytes:
        # legacy format: reserved, trigger info, payload format (DWORD slave clock), timestamp
        return struct.pack("<BBBI", 0, 0, 1, (self.t_ns // TIMESTAMP_NS) & 0xFFFFFFFF)

    # ------------------------------------------------------ allocation
    @staticmethod
    def _check_idle(dl: DaqList) -> None:
        """A running or selected list keeps its layout and mode (ERR_DAQ_ACTIVE)."""
        if dl.running or dl.selected:
            raise DaqError(ERR_DAQ_ACTIVE)

    def _free(self, cto: bytes) -> bytes:
        self.stop_all()
        self.lists.clear()
        self._ptr = None
        self._entries = 0
        self._state = "free"
        return b""

    def _alloc_daq(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        if self._state != "free" or self.lists:
            raise DaqError(ERR_SEQUENCE)
        count = struct.unpack_from("<H", cto, 2)[0]
        if count > self.cfg.max_daq_lists:
            raise DaqError(ERR_MEMORY_OVERFLOW)
        self.lists = [DaqList() for _ in range(count)]
        self._state = "daq"
        return b""

    def _alloc_odt(self, cto: bytes) -> bytes:
        self._need(cto, 5)
        if self._state not in ("daq", "odt"):
            raise DaqError(ERR_SEQUENCE)
        dl = self._list(cto)
        for d in self.lists:  # new ODTs renumber the later lists' PIDs
            self._check_idle(d)
        count = cto[4]
        total = sum(len(d.odts) for d in self.lists) + count
        if total > MAX_PID + 1:
            raise DaqError(ERR_MEMORY_OVERFLOW)
        dl.odts.extend([] for _ in range(count))
        pid = 0
        for d in self.lists:  # absolute ODT numbers: lists in order
            d.first_pid = pid
            pid += len(d.odts)
        self._state = "odt"
        return b""

    def _alloc_entry(self, cto: bytes) -> bytes:
        self._need(cto, 6)
        if self._state not in ("odt", "entry"):
            raise DaqError(ERR_SEQUENCE)
        dl = self._list(cto)
        self._check_idle(dl)
        odt = cto[4]
        if odt >= len(dl.odts):
            raise DaqError(ERR_OUT_OF_RANGE)
        count = cto[5]  # 0: an ODT with no entry (the first, holding only the timestamp)
        if count > MAX_DTO - 1:
            raise DaqError(ERR_OUT_OF_RANGE)
        # again for the same ODT: its entries are replaced, and so is its share of the budget
        entries = self._entries - len(dl.odts[odt]) + count
        if entries > self.cfg.max_odt_entries:
            raise DaqError(ERR_MEMORY_OVERFLOW)
        self._entries = entries
        dl.odts[odt] = [(0, 0, 0)] * count
        self._state = "entry"
        return b""

    def _clear_list(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        dl = self._list(cto)
        dl.running = dl.selected = False  # a cleared list is stopped (GET_STATUS follows)
        dl.odts = [[(0, 0, 0)] * len(odt) for odt in dl.odts]
        dl.compiled = []
        self.running = any(d.running for d in self.lists)
        return b""

    def _set_ptr(self, cto: bytes) -> bytes:
        self._need(cto, 6)
        dl = self._list(cto)
        self._check_idle(dl)
        odt, entry = cto[4], cto[5]
        if odt >= len(dl.odts) or entry >= len(dl.odts[odt]):
            raise DaqError(ERR_OUT_OF_RANGE)
        self._ptr = (struct.unpack_from("<H", cto, 2)[0], odt, entry)
        return b""

    def _write(self, cto: bytes) -> bytes:
        self._need(cto, 8)
        if self._ptr is None:
            raise DaqError(ERR_SEQUENCE)
        bit, size, ext = cto[1], cto[2], cto[3]
        address = struct.unpack_from("<I", cto, 4)[0]
        number, odt, entry = self._ptr
        dl = self.lists[number]
        self._check_idle(dl)
        if bit != 0xFF or not 1 <= size <= MAX_DTO - 1:
            raise DaqError(ERR_OUT_OF_RANGE)
        entries = dl.odts[odt]
        if entry >= len(entries):
            raise DaqError(ERR_OUT_OF_RANGE)
        others = sum(s for i, (_, s, _) in enumerate(entries) if i != entry)
        if others + size > MAX_DTO - 1:
            raise DaqError(ERR_DAQ_CONFIG)
        assert self.reader is not None
        self.reader(address, size, ext)  # raises for an address it cannot read
        entries[entry] = (address, size, ext)
        self._ptr = (number, odt, entry + 1) if entry + 1 < len(entries) else None
        return b""

    def _set_mode(self, cto: bytes) -> bytes:
        self._need(cto, 8)
        dl = self._list(cto)
        self._check_idle(dl)
        mode = cto[1]
        if mode & (MODE_STIM | MODE_DTO_CTR | MODE_PID_OFF) or mode & ~0x3A:
            raise DaqError(ERR_MODE_NOT_VALID)
        event, prescaler, priority = struct.unpack_from("<HBB", cto, 4)
        if event >= len(EVENTS) or prescaler == 0:
            raise DaqError(ERR_OUT_OF_RANGE)
        dl.mode, dl.event, dl.prescaler, dl.priority = mode, event, prescaler, priority
        return b""

    def _get_mode(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        dl = self._list(cto)
        mode = dl.mode | (0x01 if dl.selected else 0) | (0x40 if dl.running else 0)
        return struct.pack("<BHHBB", mode, 0, 0xFFFF if dl.event is None else dl.event,
                           dl.prescaler, dl.priority)

    # ---------------------------------------------------------- start / stop
    def _compile(self, dl: DaqList) -> None:
        """Check the list can run and bind each entry to its reader."""
        assert self.reader is not None
        if dl.event is None or not dl.odts:  # an ODT may be empty: its DTO is the timestamp
            raise DaqError(ERR_DAQ_CONFIG)
        compiled = []
        for i, odt in enumerate(dl.odts):
            room = MAX_DTO - 1 - (TS_SIZE if i == 0 and dl.mode & MODE_TIMESTAMP else 0)
            if any(size == 0 for _, size, _ in odt) or sum(s for _, s, _ in odt) > room:
                raise DaqError(ERR_DAQ_CONFIG)
            compiled.append([self.reader(a, s, e) for a, s, e in odt])
        dl.compiled = compiled

    def _start_stop_list(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        dl = self._list(cto)
        mode = cto[1]
        if mode == 0:
            dl.running = dl.selected = False
        elif mode in (1, 2):
            self._compile(dl)
            dl.events_seen = 0
            if mode == 1:
                dl.running = True
            else:
                dl.selected = True
        else:
            raise DaqError(ERR_MODE_NOT_VALID)
        self.running = any(d.running for d in self.lists)
        return bytes([dl.first_pid])

    def _start_stop_synch(self, cto: bytes) -> bytes:
        self._need(cto, 2)
        mode = cto[1]
        if mode == 0:
            self.stop_all()
        elif mode in (1, 3):  # start selected (3: prepare, then start at once)
            for dl in self.lists:
                if dl.selected:
                    dl.running, dl.selected, dl.events_seen = True, False, 0
        elif mode == 2:
            for dl in self.lists:
                if dl.selected:
                    dl.running = dl.selected = False
        else:
            raise DaqError(ERR_MODE_NOT_VALID)
        self.running = any(d.running for d in self.lists)
        return b""

    def stop_all(self) -> None:
        for dl in self.lists:
            dl.running = dl.selected = False
        self.running = False

    # --------------------------------------------------------------- sample
    def sample(self, t_ns: int, engine_event: bool, send: Callable[[bytes], bool]) -> None:
        """At the end of the ECU's tick: every running list whose event fired sends its ODTs."""
        budget = self.cfg.daq_frames_per_tick
        stats = self.stats
        ts = None
        for dl in self.lists:
            if not dl.running:
                continue
            ev = EVENTS[dl.event]  # type: ignore[index]  # a running list has its event set
            fired = engine_event if ev.period_ns == 0 else t_ns % ev.period_ns == 0
            if not fired:
                continue
            dl.events_seen += 1
            if dl.events_seen < dl.prescaler:
                continue
            dl.events_seen = 0
            stats.samples += 1
            for i, readers in enumerate(dl.compiled):
                if budget <= 0:
                    stats.odts_lost += len(dl.compiled) - i
                    break
                head = bytes([dl.first_pid + i])
                if i == 0 and dl.mode & MODE_TIMESTAMP:
                    if ts is None:
                        ts = struct.pack("<I", (t_ns // TIMESTAMP_NS) & 0xFFFFFFFF)
                    head += ts
                budget -= 1
                try:
                    dto = head + b"".join(r() for r in readers)
                except Exception as exc:  # noqa: BLE001 - the boundary: counted, never raised
                    stats.odts_dropped += 1
                    if self.on_read_error is not None:
                        self.on_read_error(exc)
                    continue
                if send(dto):
                    stats.odts_sent += 1
                else:
                    stats.odts_lost += 1
