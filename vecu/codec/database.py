"""Loading DBC (and ARXML / KCD / SYM) files into one cantools database and DbcCodec, all its
messages compiled once (vecu.codec.message.FrameCodec), looked up by name or by CAN ID."""

from __future__ import annotations

from collections.abc import Iterable
from importlib import resources
from pathlib import Path

import can
import cantools

from vecu.codec.e2e_layout import DbcLoadError
from vecu.codec.message import FrameCodec
from vecu.errors import ConfigError
from vecu.instances import ECU_NODE, ecu_frame_id

DEFAULT_DBC = "vecu.dbc"
TRUTH_DBC = "vecu_truth.dbc"  # debug truth frames, sent only when recording


def builtin_dbc_path(name: str = DEFAULT_DBC) -> Path:
    """Path of a DBC shipped with vecu (package data in vecu/dbc/)."""
    return Path(str(resources.files("vecu.dbc").joinpath(name)))


_ADD_BY_SUFFIX = {".arxml": "add_arxml_file", ".kcd": "add_kcd_file", ".sym": "add_sym_file"}


DATABASE_KINDS = "DBC, ARXML, KCD or SYM"
_CONTROL = bytes(range(32)).translate(None, b"\t\n\r\f")  # never in a text database


def load_database(paths: Iterable[str | Path], strict: bool = True) -> cantools.database.Database:
    """DBC files, or ARXML / KCD / SYM by their suffix, into one cantools database. A file that
    is not one is a DbcLoadError in the user's words (a CAN trace, a binary file, cantools'
    first line of a parse error); never the file's raw bytes."""
    db = cantools.database.Database(strict=strict)
    for path in paths:
        try:
            getattr(db, _ADD_BY_SUFFIX.get(Path(path).suffix.lower(), "add_dbc_file"))(str(path))
        except FileNotFoundError as exc:
            raise DbcLoadError(path, "no such file") from exc
        except Exception as exc:  # cantools raises many kinds; report them as one line
            raise DbcLoadError(path, _not_a_database(path, exc)) from exc
    return db


def _not_a_database(path: str | Path, exc: Exception) -> str:
    """Why path is no database, in one line: a trace by its suffix, binary content, or cantools'
    message (its first line, the file's text quoted only when printable)."""
    name = str(path).lower().removesuffix(".gz")
    suffix = Path(name).suffix
    if suffix in getattr(can.io.player, "MESSAGE_READERS", {}):
        return (f"a CAN trace ({suffix}), not a database: expected {DATABASE_KINDS} files "
                f"(`vecu replay` plays traces)")
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as os_exc:
        return f"cannot read: {os_exc.strerror}"
    if any(b in _CONTROL for b in head):
        return f"a binary file, not a database: expected {DATABASE_KINDS} text files"
    lines = str(exc).strip().splitlines()
    first = lines[0] if lines else type(exc).__name__
    if not first.isprintable() or len(first) > 200:
        first = first.split(":", 1)[0]  # cantools' "Invalid syntax at line L, column C"
    kind = _ADD_BY_SUFFIX.get(Path(path).suffix.lower(), "add_dbc_file")[4:-5].upper()
    return f"not a valid {kind} file: {first}"


_SHARED: dict[tuple, DbcCodec] = {}


def shared_codec(instance: int = 0) -> DbcCodec:
    """The default DbcCodec (vecu's DBC and truth DBC) of ECU instance N (vecu.instances), built
    once per process and instance while the two files are unchanged (~30 ms a build): runs share
    it, a codec being read-only once built."""
    paths = [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)]
    try:
        stamps = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in paths)
    except OSError:  # not files on a disk: nothing to tell a change by
        return DbcCodec(paths, instance=instance)
    codec = _SHARED.get((stamps, instance))
    if codec is None:
        for key in [k for k in _SHARED if k[0] != stamps]:
            del _SHARED[key]
        codec = _SHARED[stamps, instance] = DbcCodec(paths, instance=instance)
    return codec


class DbcCodec:
    """All messages of one or more DBC files, compiled once; lookup by name or by CAN ID.

    The default is vecu's own DBC plus its truth DBC (the ECU knows the truth IDs and ignores them).
    instance: the ECU instance whose frames this codec sends or reads: every message the DBCs
    give the ECU node (VECU) as a sender is at its ID moved by vecu.instances.ecu_frame_id (its
    E2E data ID with it); 0 leaves every ID as the DBC has it.
    """

    def __init__(self, paths: Iterable[str | Path] | None = None, strict: bool = True,
                 fast: bool = True, instance: int = 0) -> None:
        paths = (list(paths) if paths is not None
                 else [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC)])
        self.paths = [str(p) for p in paths]
        self.instance = instance
        self._db = load_database(paths, strict=strict)
        if instance:
            _move_ecu_frames(self._db, instance)
        self._by_name = {m.name: FrameCodec(m, fast) for m in self._db.messages}
        self.by_id: dict[tuple[int, bool], FrameCodec] = {
            (c.frame_id, c.is_extended): c for c in self._by_name.values()
        }

    def __getitem__(self, name: str) -> FrameCodec:
        return self._by_name[name]

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def lookup(self, msg: can.Message) -> FrameCodec | None:
        return self.by_id.get((msg.arbitration_id, msg.is_extended_id))

    def sent_by(self, node: str) -> set[tuple[int, bool]]:
        """(CAN ID, extended) of every message the DBC(s) give `node` as a sender."""
        return {(fc.frame_id, fc.is_extended) for fc in self._by_name.values()
                if node in fc.senders}


def _move_ecu_frames(db: cantools.database.Database, instance: int) -> None:
    """Put the ECU's messages of db at their IDs on `instance` (ConfigError when one leaves the
    ID range or lands on another message's ID)."""
    taken = {(m.frame_id, m.is_extended_frame): m.name for m in db.messages
             if ECU_NODE not in m.senders}
    for m in db.messages:
        if ECU_NODE in m.senders:
            m.frame_id = ecu_frame_id(m.frame_id, instance, m.is_extended_frame)
            key = (m.frame_id, m.is_extended_frame)
            if key in taken:
                raise ConfigError(f"ECU frame {m.name} of instance {instance} at 0x{m.frame_id:X} "
                                  f"clashes with {taken[key]}")
            taken[key] = m.name
    db.refresh()
