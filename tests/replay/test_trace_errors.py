"""A file that is not the trace (or the database) a command expects: one line in the user's words
naming the file and what to try, exit 2, before a summary; no Python exception text, no raw
bytes. Foreign traces: one tally line for the frames whose IDs no database knows."""

from __future__ import annotations

import logging
import re
import subprocess
import sys
from pathlib import Path

import can
import pytest

from vecu.cli import main
from vecu.replay.engine import ReplayConfig, replay

PYTHON_TEXT = re.compile(r"\w+(Error|Exception)\b|Traceback|unpack|\\x[0-9a-f]{2}")


def _frames(n: int, ids=(0x100,), extended: bool = False) -> list[can.Message]:
    return [can.Message(timestamp=1.0 + k * 0.001, arbitration_id=ids[k % len(ids)],
                        is_extended_id=extended, data=bytes([k % 256, 1, 2, 3]))
            for k in range(n)]


def _write(path: Path, msgs: list[can.Message]) -> Path:
    with can.Logger(str(path)) as w:  # python-can's writer for the suffix
        for m in msgs:
            w.on_message_received(m)
    return path


def _error_line(argv: list[str], capsys) -> str:
    rc = main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and out == "", (rc, out, err)  # no summary of nothing
    assert not PYTHON_TEXT.search(lines[0]) and lines[0].isprintable(), lines[0]
    return lines[0]


@pytest.fixture
def here(tmp_path: Path, monkeypatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_an_empty_blf(here: Path, capsys) -> None:
    (here / "x.blf").write_bytes(b"")
    assert _error_line(["replay", "x.blf"], capsys) == \
        "vecu: error: x.blf: not a BLF file (the file is empty)"


def test_another_format_named_blf_and_the_hint_that_reads_it(here: Path, capsys) -> None:
    """An ASC log saved as .blf: 'not a BLF file', and the --format the hint names reads it."""
    _write(here / "t.asc", _frames(20)).rename(here / "x.blf")
    line = _error_line(["replay", "x.blf"], capsys)
    assert line == ("vecu: error: x.blf: not a BLF file (another format? try --format asc, csv, "
                    "db, log, mf4, trc)")
    assert main(["replay", "x.blf", "--format", "asc", "--no-progress"]) == 0
    assert "frames: read 20," in capsys.readouterr().out


def test_a_plain_candump_is_not_a_candump_l_log(here: Path, capsys) -> None:
    """`candump vcan0` without -L writes '  vcan0  100   [4]  F4 00 88 13': python-can reads
    only the -L form; before, a Python unpack error after an empty summary."""
    (here / "x.log").write_text("  vcan0  100   [4]  F4 00 88 13\n  vcan0  101   [2]  01 02\n")
    line = _error_line(["replay", "x.log"], capsys)
    assert line.startswith("vecu: error: x.log: not a candump -L log (a plain candump? "
                           "python-can reads `candump -L` output only; another format? try "
                           "--format asc, blf"), line


def test_an_unknown_suffix_names_format_and_format_reads_it(here: Path, capsys) -> None:
    _write(here / "t.log", _frames(10)).rename(here / "x.candump")
    assert _error_line(["replay", "x.candump"], capsys) == (
        "vecu: error: x.candump: unknown suffix .candump: use --format (python-can reads asc, "
        "blf, csv, db, log, mf4, trc)")
    assert main(["replay", "x.candump", "--format", "log", "--no-progress"]) == 0
    assert "frames: read 10," in capsys.readouterr().out


def test_a_text_file_with_no_frames_in_a_skipping_reader(here: Path, capsys) -> None:
    """python-can's ASC reader skips lines it cannot parse: no error, no frame either."""
    (here / "x.asc").write_text("this is not\nan ASC log\n")
    assert _error_line(["replay", "x.asc"], capsys).startswith(
        "vecu: error: x.asc: no CAN frames in it (not a Vector ASC log? another format? try "
        "--format blf,")


def test_a_log_damaged_midway_keeps_what_was_read(here: Path, capsys) -> None:
    _write(here / "x.log", _frames(30))
    with open(here / "x.log", "a") as f:
        f.write("this line is not candump\n")
    assert main(["replay", "x.log", "--no-progress"]) == 2
    out, err = capsys.readouterr()
    assert "frames: read 30," in out  # the summary of what was read first
    assert err.strip() == ("vecu: error: x.log: unreadable after frame 30 (last timestamp "
                           "1.029000 s): the rest does not read as a candump -L log")


@pytest.mark.parametrize("name,content", [("x.blf", None), ("x.log", None),
                                          ("x.dbc", bytes(range(256)) * 2)])
def test_a_trace_where_a_database_is_expected(here: Path, capsys, name: str,
                                              content: bytes | None) -> None:
    """`vecu restbus x.blf` printed cantools' parse error with 150 bytes of the binary file."""
    if content is None:
        _write(here / name, _frames(5))
    else:
        (here / name).write_bytes(content)
    line = _error_line(["restbus", name, "--duration", "0.01"], capsys)
    if content is None:
        suffix = Path(name).suffix
        assert line == (f"vecu: error: {name}: a CAN trace ({suffix}), not a database: expected "
                        "DBC, ARXML, KCD or SYM files (`vecu replay` plays traces)")
    else:
        assert line == (f"vecu: error: {name}: a binary file, not a database: expected DBC, "
                        "ARXML, KCD or SYM text files")
    _write(here / "t.blf", _frames(5))  # and given to replay as the trace's database: the same
    assert _error_line(["replay", "t.blf", "--dbc", name], capsys) == line


def test_in_a_real_process(tmp_path: Path) -> None:
    (tmp_path / "x.blf").write_bytes(b"")
    res = subprocess.run([sys.executable, "-m", "vecu", "restbus", "x.blf"], capture_output=True,
                         text=True, cwd=tmp_path, timeout=120, check=False)
    assert res.returncode == 2 and res.stderr == (
        "vecu: error: x.blf: a CAN trace (.blf), not a database: expected DBC, ARXML, KCD or SYM "
        "files (`vecu replay` plays traces)\n")


def test_a_foreign_trace_is_one_tally_line_not_a_flood(tmp_path: Path, caplog) -> None:
    """Frames with IDs in no database: one warning naming how many and which IDs; the counts
    stay in the summary. (Receive problems of known IDs stay one warning each: test_engine.)"""
    trace = _write(tmp_path / "foreign.blf", _frames(60, ids=(0x123, 0x456, 0x7FF)))
    with caplog.at_level(logging.WARNING):
        res = replay(ReplayConfig(trace=str(trace), progress=False))
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert lines == [(f"{trace}: 60 frames with IDs not in the database (3 IDs: 0x123, 0x456, "
                     "0x7FF; --dbc names the trace's own database)")]
    assert res.summary["frames"]["unknown_id"] == 60 and res.error is None
