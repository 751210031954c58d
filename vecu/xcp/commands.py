"""The XCP command processor (ASAM MCD-1 XCP 1.5): one CTO in, its responses out.

Standard (CONNECT … GET_ID, SET_MTA, UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM, GET_SEED / UNLOCK),
calibration (DOWNLOAD, DOWNLOAD_NEXT, DOWNLOAD_MAX, SHORT_DOWNLOAD), page switching (GET /
SET_CAL_PAGE, COPY_CAL_PAGE) and DAQ (daq.py). Intel byte order, byte granularity, MAX_CTO =
MAX_DTO = 8 (CAN). Every refused command gets its error packet (0xFE, code) and changes nothing;
while disconnected every command but CONNECT is ignored (the standard's rule).

Calibration: a write to the calibration segment's working page is staged; once a leaf's bytes
are all written (a float may span two DOWNLOADs) its value is checked (the leaf's bounds, its
config, the tree's validation: calibration.Calibrator) and, if accepted, taken by the ECU from
its next tick; a refused value answers ERR_OUT_OF_RANGE and keeps the old bytes. Leaves the
running ECU cannot take (its function's calibrations()) and the reference page are ERR_WRITE_PROTECTED.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from vecu.params import ParamError
from vecu.xcp.calibration import Calibrator
from vecu.xcp.config import XcpConfig
from vecu.xcp.daq import Daq, DaqError
from vecu.xcp.measurements import Measurement
from vecu.xcp.memory import CAL_BASE, ID_BASE, MEAS_BASE, CalSegment
from vecu.xcp.security import SeedKey, SeedKeyError

OK, ERR, EV = 0xFF, 0xFE, 0xFD
# error codes (XCP 1.5 Part 2, 1.7.3.3)
ERR_CMD_SYNCH, ERR_CMD_BUSY, ERR_DAQ_ACTIVE = 0x00, 0x10, 0x11
ERR_CMD_UNKNOWN, ERR_CMD_SYNTAX, ERR_OUT_OF_RANGE = 0x20, 0x21, 0x22
ERR_WRITE_PROTECTED, ERR_ACCESS_DENIED, ERR_ACCESS_LOCKED = 0x23, 0x24, 0x25
ERR_PAGE_NOT_VALID, ERR_MODE_NOT_VALID, ERR_SEGMENT_NOT_VALID = 0x26, 0x27, 0x28
ERR_SEQUENCE, ERR_DAQ_CONFIG, ERR_MEMORY_OVERFLOW, ERR_GENERIC = 0x29, 0x2A, 0x30, 0x31
# resources (CONNECT, GET_STATUS, GET_SEED, UNLOCK)
CAL_PAG, DAQ_RES, STIM, PGM = 0x01, 0x04, 0x08, 0x10
MAX_CTO = MAX_DTO = 8
PROTOCOL_VERSION = TRANSPORT_VERSION = 1
XCP_CRC_32 = 0x09
MAX_CHECKSUM_BLOCK = 0x0100_0000
WORKING, REFERENCE = 0, 1  # logical pages of segment 0
# GET_ID types: 0 ASCII text, 1 A2L name without path/extension, 4 the A2L itself (upload)
ID_TEXT, ID_A2L_NAME, ID_A2L_FILE = 0, 1, 4
MAX_BS = 36  # master block mode: DOWNLOAD_NEXT packets of 6 bytes, 216 bytes per block


class XcpError(Exception):
    """A refused command: its XCP error code (and the bytes that follow it in the error
    packet, e.g. DOWNLOAD_NEXT's expected count)."""

    def __init__(self, code: int, extra: bytes = b"") -> None:
        super().__init__(code)
        self.code = code
        self.extra = extra


@dataclass
class XcpStats:
    commands: int = 0
    positive: int = 0
    negative: int = 0
    ignored: int = 0            # commands while disconnected
    calibrations: int = 0       # leaves written and taken
    refused_writes: int = 0     # out of bounds / write protected
    connects: int = 0
    block_rest_dropped: int = 0  # DOWNLOAD_NEXT packets of a refused block, not answered


class CommandProcessor:
    """The slave's protocol state and its commands; handle() maps one CTO to its responses."""

    def __init__(self, cfg: XcpConfig, segment: CalSegment, calibrator: Calibrator,
                 reference_tree: Any, measurements: list[Measurement], daq: Daq,
                 security: SeedKey, a2l_text: Callable[[], str]) -> None:
        self.cfg = cfg
        self.segment = segment
        self.cal = calibrator
        self.reference = segment.image(reference_tree)
        self.working = segment.image(calibrator.tree)
        self.working_tree = calibrator.tree  # the working page's values (the ECU's, on it)
        self.reference_tree = reference_tree
        self.meas = measurements
        self.meas_end = (measurements[-1].address + measurements[-1].size) if measurements \
            else MEAS_BASE
        self.daq = daq
        self.security = security
        self._a2l_text = a2l_text
        self.stats = XcpStats()
        self.connected = False
        self.mta = 0
        self.mta_ext = 0
        self.xcp_page = WORKING
        self.ecu_page = WORKING
        self.id_bytes = b""
        self._staged: dict[int, int] = {}  # segment offset -> byte written, leaf not complete
        self._block_left = 0               # master block mode: bytes still to come
        self._refused_left = 0             # ... of a refused block (dropped, not answered)
        self.t_ns = 0
        self._cmds: dict[int, Callable[[bytes], bytes | list[bytes]]] = {
            0xFF: self._connect, 0xFE: self._disconnect, 0xFD: self._get_status,
            0xFC: self._synch, 0xFB: self._comm_mode_info, 0xFA: self._get_id,
            0xF8: self._get_seed, 0xF7: self._unlock, 0xF6: self._set_mta, 0xF5: self._upload,
            0xF4: self._short_upload, 0xF3: self._build_checksum, 0xF0: self._download,
            0xEF: self._download_next, 0xEE: self._download_max, 0xED: self._short_download,
            0xEB: self._set_cal_page, 0xEA: self._get_cal_page, 0xE4: self._copy_cal_page,
            0xE9: self._pag_processor_info, 0xE8: self._segment_info, 0xE7: self._page_info,
            **daq.commands(),
        }
        # the resource each command group needs unlocked (seed & key)
        self._resource = {cmd: CAL_PAG for cmd in (0xF0, 0xEF, 0xEE, 0xED, 0xEB, 0xE4)}
        self._resource.update({cmd: DAQ_RES for cmd in daq.commands()})
        daq.reader = self.entry_reader
        daq.on_event_name = self._event_name

    def _event_name(self, name: bytes) -> None:
        """GET_DAQ_EVENT_INFO puts the event's name at the MTA (to upload)."""
        self.id_bytes = name
        self.mta, self.mta_ext = ID_BASE, 0

    def entry_reader(self, address: int, size: int, ext: int) -> Callable[[], bytes]:
        """A DAQ entry's sampler: measurements and the calibration segment only (areas of a
        fixed size); ERR_ACCESS_DENIED elsewhere (the GET_ID area is uploadable, not
        measurable: its length changes with every GET_ID)."""
        if ext != 0:
            raise XcpError(ERR_OUT_OF_RANGE)
        end = address + size
        if not (MEAS_BASE <= address and end <= self.meas_end
                or CAL_BASE <= address and end <= CAL_BASE + self.segment.size):
            raise XcpError(ERR_ACCESS_DENIED)
        for m in self.meas:
            if m.address == address and m.size == size:
                return m.pack
        return lambda: self.read(address, size, ext)

    # ------------------------------------------------------------------ entry
    def handle(self, cto: bytes, t_ns: int) -> list[bytes]:
        """The response packets to one command (none: ignored while disconnected, or a
        DOWNLOAD_NEXT in the middle of a block)."""
        self.t_ns = self.daq.t_ns = t_ns
        stats = self.stats
        if not cto:
            return []
        pid = cto[0]
        if not self.connected and pid != 0xFF:
            stats.ignored += 1
            return []
        if self._refused_left:  # the rest of a refused block: its one answer was the error
            if pid == 0xEF and len(cto) >= 2 and cto[1] == self._refused_left:
                self._refused_left -= min(cto[1], MAX_CTO - 2)
                stats.block_rest_dropped += 1
                return []
            self._refused_left = 0
        stats.commands += 1
        if self._block_left and pid != 0xEF:  # a block broken off: its bytes are dropped
            self._block_left = 0
            self._staged.clear()
            if pid in (0xF0, 0xEE):  # a write instead of the block's DOWNLOAD_NEXT
                stats.negative += 1
                self._refused_left = self._block_rest(cto)
                return [bytes([ERR, ERR_SEQUENCE])]
        fn = self._cmds.get(pid)
        try:
            if fn is None:
                raise XcpError(ERR_CMD_UNKNOWN)
            res = self._resource.get(pid)
            if res is not None and self.security.locked & res:
                raise XcpError(ERR_ACCESS_LOCKED)
            out = fn(cto)
        except (XcpError, SeedKeyError, DaqError) as exc:
            stats.negative += 1
            if isinstance(exc, SeedKeyError) and exc.disconnect:
                self._disconnect(cto)
            if pid in (0xF0, 0xEF, 0xEE, 0xED):
                self._block_left = 0
                self._staged.clear()
                self._refused_left = self._block_rest(cto)
            return [bytes([ERR, exc.code]) + getattr(exc, "extra", b"")]
        stats.positive += 1
        if isinstance(out, list):
            return out
        return [bytes([OK]) + out]

    @staticmethod
    def _block_rest(cto: bytes) -> int:
        """Bytes of a master block still to come after this DOWNLOAD / DOWNLOAD_NEXT packet
        (0: not a block's packet)."""
        if len(cto) < 2 or cto[0] not in (0xF0, 0xEF) or cto[1] <= MAX_CTO - 2:
            return 0
        return cto[1] - (MAX_CTO - 2)

    @staticmethod
    def _need(cto: bytes, n: int) -> None:
        if len(cto) < n:
            raise XcpError(ERR_CMD_SYNTAX)

    # --------------------------------------------------------------- standard
    def _connect(self, cto: bytes) -> bytes:
        # a CONNECT without its mode byte (1 byte, as some testers send it) is mode 0 (normal)
        mode = cto[1] if len(cto) > 1 else 0
        if mode not in (0, 1):  # normal, user-defined
            raise XcpError(ERR_OUT_OF_RANGE)
        if not self.connected:
            self.stats.connects += 1
            self.security.lock_all()
        self.connected = True
        self._block_left = 0
        self._staged.clear()
        # byte order Intel, byte granularity, slave block mode, GET_COMM_MODE_INFO available
        comm_mode = 0x40 | 0x80
        return struct.pack("<BBBHBB", CAL_PAG | DAQ_RES | PGM, comm_mode, MAX_CTO, MAX_DTO,
                           PROTOCOL_VERSION, TRANSPORT_VERSION)

    def _disconnect(self, cto: bytes) -> bytes:
        self.connected = False
        self.daq.stop_all()
        self.security.lock_all()
        return b""

    def _get_status(self, cto: bytes) -> bytes:
        session = 0x40 if self.daq.running else 0
        return struct.pack("<BBBH", session, self.security.locked, 0, 0)

    def _synch(self, cto: bytes) -> bytes:
        raise XcpError(ERR_CMD_SYNCH)

    def _comm_mode_info(self, cto: bytes) -> bytes:
        # master block mode; MAX_BS, MIN_ST 0, no queue; driver version 1.0
        return struct.pack("<BBBBBBB", 0, 0x01, 0, MAX_BS, 0, 0, 0x10)

    def _get_id(self, cto: bytes) -> bytes:
        self._need(cto, 2)
        kind = cto[1]
        if kind == ID_TEXT:
            text = f"vecu virtual ECU ({self.cfg.a2l_name})".encode("ascii")
        elif kind == ID_A2L_NAME:
            text = self.cfg.a2l_name.encode("ascii")
        elif kind == ID_A2L_FILE:
            text = self._a2l_text().encode("utf-8")
        else:  # not available: length 0
            return struct.pack("<BHI", 0, 0, 0)
        self.id_bytes = text
        self.mta, self.mta_ext = ID_BASE, 0
        return struct.pack("<BHI", 0, 0, len(text))  # mode 0: upload it from the MTA

    def _get_seed(self, cto: bytes) -> bytes:
        self._need(cto, 3)
        return self.security.get_seed(cto[1], cto[2])

    def _unlock(self, cto: bytes) -> bytes:
        self._need(cto, 2)
        return self.security.unlock(cto[1], cto[2:2 + min(cto[1], 6)])

    def _set_mta(self, cto: bytes) -> bytes:
        self._need(cto, 8)
        self.mta_ext = cto[3]
        self.mta = struct.unpack_from("<I", cto, 4)[0]
        return b""

    # ------------------------------------------------------------------ read
    def read(self, address: int, n: int, ext: int = 0) -> bytes:
        """n bytes from the slave's memory; ERR_ACCESS_DENIED outside the mapped areas."""
        if ext != 0:
            raise XcpError(ERR_OUT_OF_RANGE)
        end = address + n
        seg = self.segment
        if CAL_BASE <= address and end <= CAL_BASE + seg.size:
            page = self.working if self.xcp_page == WORKING else self.reference
            return bytes(page[address - CAL_BASE:end - CAL_BASE])
        if MEAS_BASE <= address and end <= self.meas_end:
            out = bytearray(n)
            for m in self.meas:
                if m.address < end and address < m.address + m.size:
                    data = m.pack()
                    lo = max(address, m.address)
                    hi = min(end, m.address + m.size)
                    out[lo - address:hi - address] = data[lo - m.address:hi - m.address]
            return bytes(out)
        if ID_BASE <= address and end <= ID_BASE + len(self.id_bytes):
            return self.id_bytes[address - ID_BASE:end - ID_BASE]
        raise XcpError(ERR_ACCESS_DENIED)

    def _upload(self, cto: bytes) -> bytes | list[bytes]:
        self._need(cto, 2)
        n = cto[1]
        if n == 0:
            raise XcpError(ERR_OUT_OF_RANGE)
        data = self.read(self.mta, n, self.mta_ext)
        self.mta += n
        if n <= MAX_CTO - 1:
            return data
        # slave block mode: consecutive responses of up to 7 bytes each
        return [bytes([OK]) + data[i:i + MAX_CTO - 1] for i in range(0, n, MAX_CTO - 1)]

    def _short_upload(self, cto: bytes) -> bytes:
        self._need(cto, 8)
        n = cto[1]
        if not 1 <= n <= MAX_CTO - 1:
            raise XcpError(ERR_OUT_OF_RANGE)
        address = struct.unpack_from("<I", cto, 4)[0]
        data = self.read(address, n, cto[3])
        self.mta, self.mta_ext = address + n, cto[3]
        return data

    def _build_checksum(self, cto: bytes) -> bytes:
        self._need(cto, 8)
        size = struct.unpack_from("<I", cto, 4)[0]
        if size == 0 or size > MAX_CHECKSUM_BLOCK:
            raise XcpError(ERR_OUT_OF_RANGE)
        crc = zlib.crc32(self.read(self.mta, size, self.mta_ext))
        self.mta += size
        return struct.pack("<BBBI", XCP_CRC_32, 0, 0, crc)

    # --------------------------------------------------------------- write
    def _write(self, address: int, data: bytes, ext: int = 0, commit: bool = True) -> None:
        """Stage bytes into the working page; with commit (a DOWNLOAD, or the last packet of
        a block) take every leaf whose bytes are all staged, all or none."""
        if ext != 0:
            raise XcpError(ERR_OUT_OF_RANGE)
        seg = self.segment
        end = address + len(data)
        if not (CAL_BASE <= address and end <= CAL_BASE + seg.size):
            if MEAS_BASE <= address < self.meas_end or ID_BASE <= address < ID_BASE + 0x10_0000:
                raise XcpError(ERR_WRITE_PROTECTED)
            raise XcpError(ERR_ACCESS_DENIED)
        if self.xcp_page != WORKING:
            raise XcpError(ERR_WRITE_PROTECTED)
        start = address - CAL_BASE
        if any(not leaf.writable for leaf in seg.overlapping(start, start + len(data))):
            raise XcpError(ERR_WRITE_PROTECTED)
        staged = self._staged
        for i, b in enumerate(data):
            staged[start + i] = b
        if not commit:
            return
        sets, done = [], []
        for leaf in seg.overlapping(min(staged), max(staged) + 1):
            lo = leaf.address - CAL_BASE
            offsets = range(lo, lo + leaf.size)
            if all(o in staged for o in offsets):
                sets.append((leaf.path, leaf.unpack(bytes(staged[o] for o in offsets))))
                done.append(offsets)
        if not sets:
            return
        try:
            tree = self.cal.check(sets, self.working_tree)
        except ParamError:
            self.stats.refused_writes += 1
            raise XcpError(ERR_OUT_OF_RANGE) from None  # handle() drops the staged bytes
        for offsets in done:
            for o in offsets:
                del staged[o]
        self.take(tree, self.t_ns)
        self.stats.calibrations += len(sets)

    def take(self, tree: Any, t_ns: int) -> None:
        """A checked tree becomes the working page (and the ECU's, when it runs on it)."""
        self.working[:] = self.segment.image(tree)
        self.working_tree = tree
        if self.ecu_page == WORKING:
            self.cal.apply(tree, t_ns)

    def _download(self, cto: bytes) -> bytes | list[bytes]:
        self._need(cto, 2)
        n = cto[1]
        if n == 0:
            raise XcpError(ERR_OUT_OF_RANGE)
        if n > MAX_CTO - 2:  # master block mode: the first of several packets
            if n > MAX_BS * (MAX_CTO - 2):
                raise XcpError(ERR_OUT_OF_RANGE)
            self._need(cto, MAX_CTO)
            self._write(self.mta, cto[2:MAX_CTO], self.mta_ext, commit=False)
            self.mta += MAX_CTO - 2
            self._block_left = n - (MAX_CTO - 2)
            return []
        self._need(cto, 2 + n)
        self._write(self.mta, cto[2:2 + n], self.mta_ext)
        self.mta += n
        return b""

    def _download_next(self, cto: bytes) -> bytes | list[bytes]:
        self._need(cto, 2)
        n = cto[1]
        if not self._block_left or n != self._block_left:
            expected, self._block_left = self._block_left, 0
            raise XcpError(ERR_SEQUENCE, bytes([expected]))  # with the expected count
        chunk = min(n, MAX_CTO - 2)
        self._need(cto, 2 + chunk)
        self._write(self.mta, cto[2:2 + chunk], self.mta_ext, commit=n == chunk)
        self.mta += chunk
        self._block_left -= chunk
        return [] if self._block_left else b""

    def _download_max(self, cto: bytes) -> bytes:
        self._need(cto, MAX_CTO)
        self._write(self.mta, cto[1:MAX_CTO], self.mta_ext)
        self.mta += MAX_CTO - 1
        return b""

    def _short_download(self, cto: bytes) -> bytes:
        # 8 header bytes: on classic CAN (MAX_CTO 8) there is no room for data
        self._need(cto, 8)
        n = cto[1]
        if n == 0 or 8 + n > MAX_CTO:
            raise XcpError(ERR_OUT_OF_RANGE)
        raise XcpError(ERR_CMD_SYNTAX)  # unreachable with MAX_CTO 8

    # ------------------------------------------------------------ cal pages
    def _set_cal_page(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        mode, segment, page = cto[1], cto[2], cto[3]
        if mode & ~0x83 or not mode & 0x03:
            raise XcpError(ERR_MODE_NOT_VALID)
        if segment != 0 and not mode & 0x80:
            raise XcpError(ERR_SEGMENT_NOT_VALID)
        if page not in (WORKING, REFERENCE):
            raise XcpError(ERR_PAGE_NOT_VALID)
        if mode & 0x02:
            self.xcp_page = page
        if mode & 0x01 and page != self.ecu_page:
            self.ecu_page = page  # the ECU runs on the page's values from its next tick
            self.cal.apply(self._reference_tree() if page == REFERENCE else self.working_tree,
                           self.t_ns)
        return b""

    def _reference_tree(self) -> Any:
        """The working tree with every live leaf at its reference (default) value."""
        return self.cal.check([(leaf.path, leaf.unpack(self._bytes(self.reference, leaf)))
                               for leaf in self.segment.leaves if leaf.writable],
                              self.working_tree)

    @staticmethod
    def _bytes(page: bytearray, leaf: Any) -> bytes:
        lo = leaf.address - CAL_BASE
        return bytes(page[lo:lo + leaf.size])

    def _get_cal_page(self, cto: bytes) -> bytes:
        self._need(cto, 3)
        mode, segment = cto[1], cto[2]
        if mode not in (0x01, 0x02):
            raise XcpError(ERR_MODE_NOT_VALID)
        if segment != 0:
            raise XcpError(ERR_SEGMENT_NOT_VALID)
        return bytes([0, 0, self.ecu_page if mode == 0x01 else self.xcp_page])

    def _pag_processor_info(self, cto: bytes) -> bytes:
        return bytes([1, 0])  # one segment, no FREEZE

    def _segment_info(self, cto: bytes) -> bytes:
        self._need(cto, 5)
        mode, segment, info = cto[1], cto[2], cto[3]
        if segment != 0:
            raise XcpError(ERR_SEGMENT_NOT_VALID)
        if mode == 0 and info in (0, 1):  # basic: address, length
            return struct.pack("<BBBI", 0, 0, 0, CAL_BASE if info == 0 else self.segment.size)
        if mode == 1:  # standard: 2 pages, address extension 0, no mapping, no compression
            return bytes([2, 0, 0, 0, 0])
        raise XcpError(ERR_OUT_OF_RANGE)  # mode 2: no address mapping

    def _page_info(self, cto: bytes) -> bytes:
        self._need(cto, 4)
        segment, page = cto[2], cto[3]
        if segment != 0:
            raise XcpError(ERR_SEGMENT_NOT_VALID)
        if page not in (WORKING, REFERENCE):
            raise XcpError(ERR_PAGE_NOT_VALID)
        # ECU access with and without XCP, XCP reads either way; writes only to the working page
        props = 0x0F | (0x30 if page == WORKING else 0)
        return bytes([props, 0])

    def _copy_cal_page(self, cto: bytes) -> bytes:
        self._need(cto, 5)
        src_seg, src_page, dst_seg, dst_page = cto[1:5]
        if src_seg != 0 or dst_seg != 0:
            raise XcpError(ERR_SEGMENT_NOT_VALID)
        if src_page not in (WORKING, REFERENCE) or dst_page not in (WORKING, REFERENCE):
            raise XcpError(ERR_PAGE_NOT_VALID)
        if dst_page == REFERENCE:
            raise XcpError(ERR_WRITE_PROTECTED)
        if src_page == REFERENCE:  # the working page back to the defaults (live leaves)
            self._staged.clear()
            self.take(self._reference_tree(), self.t_ns)
        return b""
