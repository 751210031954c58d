"""The CAN frames of one faulted ISO-TP exchange (ISO 15765-2:2016 §9.6, normal addressing,
classical CAN): a response segmented by hand so that one frame can be wrong on purpose, and the
flow control frames a faulted receiver sends. Only a faulted exchange goes through here; every
other one is can-isotp's (vecu.uds.transport)."""

from __future__ import annotations

from collections.abc import Callable

import can

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.uds.diag_faults.catalogue import N_BS_MS, DiagFault

PAD = 0xCC
CF_DATA = 7
FF_DATA = 6


def frame(can_id: int, data: bytes, t_ns: int, pad: int | None = PAD, fd: bool = False) -> can.Message:
    if pad is not None and len(data) < 8:
        data = data + bytes([pad]) * (8 - len(data))
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False, is_fd=fd,
                       timestamp=t_ns / NS_PER_S)


def flow_control(status: int, bs: int = 0, stmin: int = 0) -> bytes:
    """FC N_PCI: 0x3 | FS, BS, STmin (§9.6.5)."""
    return bytes([0x30 | (status & 0x0F), bs, stmin])


def stmin_ns(byte: int) -> int:
    """STmin (§9.6.5.5): 0..0x7F ms, 0xF1..0xF9 100..900 us, reserved values as 0x7F."""
    if byte <= 0x7F:
        return byte * NS_PER_MS
    if 0xF1 <= byte <= 0xF9:
        return (byte - 0xF0) * 100_000
    return 0x7F * NS_PER_MS


def fd_single_frame(payload: bytes) -> bytes:
    """A CAN FD single frame (escape SF_DL: 0x00, length) padded to a CAN FD data length."""
    data = bytes([0x00, len(payload)]) + payload
    size = next(n for n in (8, 12, 16, 20, 24, 32, 48, 64) if n >= len(data))
    return data + bytes([PAD]) * (size - len(data))


class SegmentedSender:
    """Sends `payload` from tx_id as FF + CFs, the flow control from the receiver on fc_id
    honoured (BS, STmin, WAIT), with the fault's one deviation. send(frame) puts a frame on the
    bus; poll() once per tick; on_fc() with each frame on fc_id. done when finished or given up
    (no FC within N_Bs)."""

    def __init__(self, payload: bytes, tx_id: int, send: Callable[[can.Message], object],
                 fault: DiagFault | None, value: float, t_ns: int) -> None:
        self.payload, self.tx_id, self._send = payload, tx_id, send
        self.fault = fault.name if fault is not None else ""
        self.value = int(value)
        self.done = False
        self._cfs = [payload[i:i + CF_DATA] for i in range(FF_DATA, len(payload), CF_DATA)]
        self._sent_cf = 0    # CFs of the current transfer sent
        self._sn = 1
        self._block = 0      # CFs left in the current block (0 with bs 0: unlimited)
        self._bs = 0
        self._gap_ns = 0
        self._next_ns = 0
        self._waiting_fc_since: int | None = None
        self._restarted = False
        self._first_frame(t_ns)

    def _out(self, data: bytes, t_ns: int) -> None:
        self._send(frame(self.tx_id, data, t_ns))

    def _first_frame(self, t_ns: int) -> None:
        n = len(self.payload)
        if self.fault == "ff_bad_length":
            data = bytes([0x10, self.value]) + self.payload[:FF_DATA]
        elif self.fault == "ff_escape32":
            data = b"\x10\x00" + n.to_bytes(4, "big") + self.payload[:2]
            self._cfs = [self.payload[i:i + CF_DATA] for i in range(2, n, CF_DATA)]
        else:
            data = bytes([0x10 | (n >> 8), n & 0xFF]) + self.payload[:FF_DATA]
        self._out(data, t_ns)
        self._waiting_fc_since = t_ns
        self._sent_cf, self._sn = 0, 1

    def on_fc(self, data: bytes, t_ns: int) -> None:
        if self.done or self._waiting_fc_since is None or not data or data[0] >> 4 != 3:
            return
        status = data[0] & 0x0F
        if status == 1:  # WAIT: N_Bs again
            self._waiting_fc_since = t_ns
            return
        if status != 0 or len(data) < 3:  # OVFLW or invalid: abort
            self.done = True
            return
        if self.fault == "ff_bad_length":
            return  # the receiver should not have answered; nothing more to send
        self._waiting_fc_since = None
        self._bs = data[1]
        self._block = data[1]
        self._gap_ns = stmin_ns(data[2])
        self._next_ns = t_ns

    def poll(self, t_ns: int) -> None:
        if self.done:
            return
        if self._waiting_fc_since is not None:
            if t_ns - self._waiting_fc_since > N_BS_MS * NS_PER_MS:
                self.done = True  # N_Bs: the receiver never let us go on
            return
        if t_ns < self._next_ns:
            return
        if self._sent_cf >= len(self._cfs) or (self.fault == "cf_missing"
                                               and self._sent_cf >= self.value):
            self.done = True
            return
        sn = self._sn
        if self.fault == "cf_wrong_sn" and self._sent_cf == 1:
            sn = (sn + self.value) & 0x0F
        self._out(bytes([0x20 | sn]) + self._cfs[self._sent_cf], t_ns)
        if self.fault == "cf_repeated_sn" and self._sent_cf == 0:
            self._out(bytes([0x20 | sn]) + self._cfs[0], t_ns)
        self._sent_cf += 1
        self._sn = (self._sn + 1) & 0x0F
        self._next_ns = t_ns + self._gap_ns
        if self._sent_cf == 1 and not self._restarted:
            if self.fault == "sf_during_rx":
                self._out(bytes([0x03, 0x7F, self.payload[0] - 0x40, 0x10]), t_ns)
                self.done = True
                return
            if self.fault == "ff_during_rx":
                self._restarted = True
                self.fault = ""
                self._first_frame(t_ns)
                return
        if self._bs:
            self._block -= 1
            if self._block == 0 and self._sent_cf < len(self._cfs):
                self._waiting_fc_since = t_ns
