"""End-to-end protection: the AUTOSAR E2E profiles P01, P02, P04, P05, P07 and P11 through the
`autosar-e2e` package (its C implementation computes and checks every CRC; vecu has no CRC table).

A profile is one entry of `PROFILES` (where its header lies, its counter's range, its data ID
modes and the library's protect / check functions). An `E2EProtection` binds a profile to one
message: data ID (P02: a list of 16), data ID mode, header offset and protected length.
vecu's own safety frames use P11 with the data ID = the CAN ID, mode "both"
(docs/restbus.md, "vecu's own frames").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import e2e as autosar_e2e


@dataclass(frozen=True)
class Profile:
    """One AUTOSAR E2E profile as autosar-e2e implements it (offsets from the header's start)."""

    name: str
    header_bytes: int        # the E2E header's size (CRC, counter and whatever else it holds)
    crc_at: int              # the CRC's first byte
    crc_bytes: int
    counter_at: int          # the counter's first byte
    counter_bytes: int       # 0: the low nibble of byte counter_at
    counter_modulo: int      # counter values 0 .. modulo - 1, then 0 again
    modes: dict[str, int]    # data_id_mode names -> the library's constants ({}: no modes)
    data_id_bits: int        # 0: a list of 16 data IDs (P02)
    takes_offset: bool
    protect: Callable[..., None]
    check: Callable[..., bool]


def _nibble_modes(module) -> dict[str, int]:
    prefix = module.__name__.rsplit(".", 1)[-1].upper()
    return {name.lower(): getattr(module, f"E2E_{prefix}_DATAID_{name}")
            for name in ("BOTH", "ALT", "LOW", "NIBBLE")
            if hasattr(module, f"E2E_{prefix}_DATAID_{name}")}


_L = autosar_e2e
PROFILES: dict[str, Profile] = {p.name: p for p in (
    Profile("P01", 2, 0, 1, 1, 0, 15, _nibble_modes(_L.p01), 16, True,
            _L.p01.e2e_p01_protect, _L.p01.e2e_p01_check),
    Profile("P02", 2, 0, 1, 1, 0, 16, {}, 0, False,
            _L.p02.e2e_p02_protect, _L.p02.e2e_p02_check),
    Profile("P04", 12, 8, 4, 2, 2, 1 << 16, {}, 32, True,
            _L.p04.e2e_p04_protect, _L.p04.e2e_p04_check),
    Profile("P05", 3, 0, 2, 2, 1, 1 << 8, {}, 16, True,
            _L.p05.e2e_p05_protect, _L.p05.e2e_p05_check),
    Profile("P07", 20, 0, 8, 12, 4, 1 << 32, {}, 32, True,
            _L.p07.e2e_p07_protect, _L.p07.e2e_p07_check),
    Profile("P11", 2, 0, 1, 1, 0, 15, _nibble_modes(_L.p11), 16, True,
            _L.p11.e2e_p11_protect, _L.p11.e2e_p11_check),
)}


class E2EConfigError(ValueError):
    """An E2E configuration a message cannot carry (the message is for the caller to name)."""


@dataclass(frozen=True)
class E2EProtection:
    """One message's E2E protection. length: bytes protected (0: the whole payload)."""

    profile: str
    data_id: int = 0
    data_id_list: tuple[int, ...] = ()
    data_id_mode: str = "both"
    offset: int = 0
    length: int = 0
    _kw: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        kind = PROFILES.get(self.profile.upper())
        if kind is None:
            raise E2EConfigError(f"unknown E2E profile {self.profile!r} "
                                 f"(known: {', '.join(PROFILES)})")
        object.__setattr__(self, "profile", kind.name)
        kw: dict[str, object] = {"length": self.length}
        if kind.data_id_bits:
            if not 0 <= self.data_id < (1 << kind.data_id_bits):
                raise E2EConfigError(f"{kind.name}: data_id {self.data_id:#x} does not fit in "
                                     f"{kind.data_id_bits} bits")
            kw["data_id"] = self.data_id
        else:
            ids = self.data_id_list
            if len(ids) != 16 or not all(0 <= i <= 0xFF for i in ids):
                raise E2EConfigError(f"{kind.name}: data_id_list needs 16 values 0..255, got "
                                     f"{list(ids)}")
            kw["data_id_list"] = bytes(ids)
        if kind.modes:
            mode = self.data_id_mode.lower()
            if mode not in kind.modes:
                raise E2EConfigError(f"{kind.name}: unknown data_id_mode {self.data_id_mode!r} "
                                     f"(known: {', '.join(kind.modes)})")
            kw["data_id_mode"] = kind.modes[mode]
        if kind.takes_offset:
            kw["offset"] = self.offset
        elif self.offset:
            raise E2EConfigError(f"{kind.name}: the header sits at byte 0 (no offset)")
        if self.offset < 0 or self.length < 0:
            raise E2EConfigError("offset and length must be >= 0")
        self._kw.update(kw)

    @property
    def kind(self) -> Profile:
        return PROFILES[self.profile]

    @property
    def counter_modulo(self) -> int:
        return self.kind.counter_modulo

    @property
    def crc_span(self) -> tuple[int, int]:
        """(first, last + 1) byte of the CRC in the payload."""
        start = self.offset + self.kind.crc_at
        return start, start + self.kind.crc_bytes

    def fits(self, payload_length: int) -> str | None:
        """Why a payload of this many bytes cannot carry the protection (None: it can)."""
        need = self.offset + self.kind.header_bytes
        covered = self.length or payload_length
        if covered > payload_length:
            return f"length {covered} exceeds the message's {payload_length} bytes"
        if need > covered:
            return (f"{self.profile} needs {need} bytes (header of {self.kind.header_bytes} at "
                    f"offset {self.offset}), the message protects {covered}")
        return None

    def _id_only(self) -> int | bytes | None:
        """The data ID (P02: the list) when every other argument of the library's calls is at
        its default (length 0, offset 0, data ID mode "both"; P02's check has no default
        length): the calls then pass it positionally, no keywords (a keyword argument costs
        autosar-e2e's C call ~0.25 us of parsing). None: the keyword call."""
        kind, kw = self.kind, self._kw
        if (kind.name == "P02" or kw.get("length", 0) or kw.get("offset", 0)
                or kw.get("data_id_mode", kind.modes.get("both")) != kind.modes.get("both")):
            return None
        return kw.get("data_id", kw.get("data_id_list"))

    def protector(self) -> Callable[[bytearray], None]:
        """protect(buf): the CRC (and P04/P07's length and data ID fields) written in place,
        the counter left as it is in buf."""
        keep = partial(self.kind.protect, increment_counter=False, **self._kw)
        data_id = self._id_only()
        if data_id is None or not _increments_nibble(self.kind):
            return keep
        # a nibble counter (P01, P11) below its modulo: the library's own increment from the
        # value before it, without the increment_counter keyword (checked on samples above)
        protect, at, modulo = self.kind.protect, self.kind.counter_at, self.kind.counter_modulo

        def protect_in_place(buf: bytearray) -> None:
            b = buf[at]
            c = b & 0x0F
            if c >= modulo:
                keep(buf)
                return
            buf[at] = (b & 0xF0) | (c - 1 if c else modulo - 1)
            protect(buf, data_id)
        return protect_in_place

    def checker(self) -> Callable[[bytes | bytearray], bool]:
        """ok(payload): the library's check (CRC, and what else the profile's header holds)."""
        data_id = self._id_only()
        if data_id is None:
            keyword = partial(self.kind.check, **self._kw)

            def ok(data: bytes | bytearray) -> bool:
                try:
                    return keyword(data if type(data) is bytearray else bytearray(data))
                except ValueError:  # a payload too short for the header
                    return False
            return ok
        check = self.kind.check

        def ok_id(data: bytes | bytearray) -> bool:
            try:
                return check(data if type(data) is bytearray else bytearray(data), data_id)
            except ValueError:  # a payload too short for the header
                return False
        return ok_id

    def counter(self, data: bytes | bytearray) -> int:
        kind = self.kind
        at = self.offset + kind.counter_at
        if kind.counter_bytes == 0:
            return data[at] & 0x0F
        return int.from_bytes(data[at:at + kind.counter_bytes], "big")

    def set_counter(self, buf: bytearray, value: int) -> None:
        """Write the counter (any int: taken modulo the field's size, not the profile's range,
        so that a disturbance can send a value the profile forbids)."""
        kind = self.kind
        at = self.offset + kind.counter_at
        if kind.counter_bytes == 0:
            buf[at] = (buf[at] & 0xF0) | (value & 0x0F)
            return
        n = kind.counter_bytes
        buf[at:at + n] = (value % (1 << (8 * n))).to_bytes(n, "big")


_NIBBLE_INCREMENT: dict[str, bool] = {}  # profile name -> _increments_nibble's finding


def _increments_nibble(kind: Profile) -> bool:
    """The library's counter increment of a nibble-counter profile (P01, P11) is (c + 1) mod
    the profile's modulo in the low nibble of byte counter_at, the high nibble and the rest
    kept: protecting with the increment from the counter before gives what protecting without
    it gives, for every counter value below the modulo (checked once per profile on sample
    payloads; False: the keyword call)."""
    found = _NIBBLE_INCREMENT.get(kind.name)
    if found is None:
        found = _NIBBLE_INCREMENT[kind.name] = _check_nibble_increment(kind)
    return found


def _check_nibble_increment(kind: Profile) -> bool:
    if kind.counter_bytes != 0 or kind.counter_modulo > 16 or not kind.data_id_bits:
        return False
    at, modulo = kind.counter_at, kind.counter_modulo
    for data_id in (0x0200, 0x1234):
        for c in range(modulo):
            for high in (0x00, 0xA0, 0xF0):
                want = bytearray(8)
                want[at] = high | c
                want[-1] = 0x5A ^ c
                got = bytearray(want)
                got[at] = high | (c - 1 if c else modulo - 1)
                try:
                    kind.protect(want, data_id=data_id, increment_counter=False)
                    kind.protect(got, data_id)
                except Exception:  # noqa: BLE001 - any surprise: the keyword call
                    return False
                if got != want:
                    return False
    return True


def own_protection(can_id: int) -> E2EProtection:
    """vecu's own safety frames: P11, data ID = the CAN ID, both bytes of it (docs/restbus.md)."""
    return E2EProtection("P11", data_id=can_id, data_id_mode="both")


class AliveCounterCheck:
    """Receiver side of an alive counter: accepts +1 (mod `modulo`); flags repeats and jumps.

    After an error the next counter is accepted as the new reference (resynchronisation).
    """

    def __init__(self, modulo: int = 16, max_delta: int = 1) -> None:
        self.modulo = modulo
        self.max_delta = max_delta
        self._last: int | None = None

    def check(self, counter: int) -> bool:
        last = self._last
        if counter >= self.modulo:  # a value the profile never sends
            self._last = None
            return False
        self._last = counter
        if last is None:
            return True
        delta = (counter - last) % self.modulo
        return 1 <= delta <= self.max_delta

    def reset(self) -> None:
        self._last = None
