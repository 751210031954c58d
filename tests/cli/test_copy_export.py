"""`vecu scenario copy NAME DIR` (a shipped scenario with its companion files runs as is from
the copy) and `vecu dbc export DIR` (vecu's DBCs, and one merged DBC that cantools loads alone
and that decodes every frame of a `vecu run --log`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest

from vecu.cli import build_parser, run_command
from vecu.codec import DEFAULT_DBC, TRUTH_DBC, builtin_dbc_path
from vecu.scenario.loader import companion_files, load_scenario
from vecu.shipped import shipped_files

ENV = {**os.environ, "VECU_KERNELS": "python"}
WITH_COMPANIONS = [name for name, path in shipped_files("scenario").items()
                   if companion_files(path)]


def vecu(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                          env=ENV, cwd=cwd, timeout=300, check=False)


def test_some_shipped_scenario_has_companions():
    assert "restbus_body_e2e" in WITH_COMPANIONS


@pytest.mark.parametrize("name", WITH_COMPANIONS)
def test_a_copied_scenario_runs_as_is_on_its_copied_files(name, tmp_path):
    source = shipped_files("scenario")[name]
    res = vecu("scenario", "copy", name, "mine", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    copy = tmp_path / "mine" / f"{name}.toml"
    assert copy.read_bytes() == source.read_bytes()  # nothing rewritten
    for rel in companion_files(source):
        assert (copy.parent / rel).read_bytes() == (source.parent / rel).read_bytes()
    restbus = load_scenario(copy).config.restbus
    used = [*restbus.databases, restbus.e2e_path, restbus.values_path]
    assert all(Path(p).resolve().is_relative_to(tmp_path) for p in used if p), used
    res = vecu("scenario", "run", str(copy), cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "vecu scenario: 1/1 passed" in res.stdout


def test_copy_never_overwrites_unless_forced(tmp_path, capsys):
    name = WITH_COMPANIONS[0]
    args = ["scenario", "copy", name, str(tmp_path)]
    (tmp_path / "restbus").mkdir()
    mine = tmp_path / "restbus" / "body.dbc"
    mine.write_text("mine")
    assert run_command(build_parser().parse_args(args)) == 2
    assert "body.dbc: exists (--force overwrites)" in capsys.readouterr().err
    assert mine.read_text() == "mine" and not (tmp_path / f"{name}.toml").exists()
    assert run_command(build_parser().parse_args([*args, "--force"])) == 0
    assert mine.read_text() != "mine"


def test_the_merged_dbc_decodes_every_frame_of_a_run_log(tmp_path):
    res = vecu("run", "--duration", "0.5", "--log", "run.log", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert run_command(build_parser().parse_args(["dbc", "export", str(tmp_path / "dbc")])) == 0
    for name in (DEFAULT_DBC, TRUTH_DBC):
        assert (tmp_path / "dbc" / name).read_bytes() == builtin_dbc_path(name).read_bytes()
    merged = cantools.database.load_file(str(tmp_path / "dbc" / "vecu_all.dbc"))
    parts = [cantools.database.load_file(str(builtin_dbc_path(n))) for n in (DEFAULT_DBC, TRUTH_DBC)]
    assert sorted(m.name for m in merged.messages) == sorted(
        m.name for db in parts for m in db.messages)
    frames = list(can.LogReader(str(tmp_path / "run.log")))
    ids = {m.arbitration_id for m in frames}
    assert len(frames) > 1000 and {0x100, 0x200, 0x300} <= ids
    assert ids & {m.frame_id for m in parts[1].messages}  # truth frames are in the log
    for frame in frames:
        merged.decode_message(frame.arbitration_id, frame.data)  # raises on an unknown ID
    assert all(merged.get_message_by_frame_id(i) for i in ids)


def test_export_with_an_instance_moves_the_ecu_ids(tmp_path):
    assert run_command(build_parser().parse_args(
        ["dbc", "export", str(tmp_path), "--instance", "1"])) == 0
    merged = cantools.database.load_file(str(tmp_path / "vecu_all.dbc"))
    assert merged.get_message_by_name("ECU_ThrottleEstimate").frame_id == 0x200 + 0x60
    assert merged.get_message_by_name("TPS_Sensor").frame_id == 0x100


@pytest.mark.parametrize("argv", [["dbc", "export"], ["scenario", "copy", "tps_dead"]])
def test_a_bad_directory_is_one_line_before_any_work(argv, tmp_path, capsys):
    afile = tmp_path / "x.blf"
    afile.write_text("")
    assert run_command(build_parser().parse_args([*argv, str(afile / "sub")])) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"vecu: error: {afile / 'sub'}: "), err
    assert "is a file, not a directory" in err[0], err
    assert not (tmp_path / "x.blf" / "sub").exists()
