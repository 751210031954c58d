"""Shipped scenarios and campaigns by name (vecu.shipped, `vecu scenario|campaign list|show|run`),
`vecu --version`, and the outputs line of `vecu run`."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from vecu.cli import build_parser, run_command
from vecu.cli.run import outputs_line
from vecu.errors import BadFileError
from vecu.shipped import describe, resolve, shipped_files

DATA = Path(__file__).resolve().parents[2] / "vecu" / "data"


def vecu(argv: list[str]) -> int:
    return run_command(build_parser().parse_args(argv))


@pytest.mark.parametrize("kind,folder,at_least", [("scenario", "scenarios", 17),
                                                   ("campaign", "campaigns", 3)])
def test_shipped_files_are_the_package_data_folder(kind, folder, at_least):
    files = shipped_files(kind)
    assert len(files) >= at_least
    assert sorted(p.resolve() for p in files.values()) == sorted(
        p.resolve() for p in (DATA / folder).glob("*.toml"))
    assert all(name == path.stem for name, path in files.items())
    assert list(files) == sorted(files)


def test_a_name_finds_the_shipped_file_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve("scenario", "tps_dead") == shipped_files("scenario")["tps_dead"]
    assert resolve("scenario", "tps_dead.toml") == shipped_files("scenario")["tps_dead"]
    assert resolve("campaign", "tps-kill-latency").parent.name == "campaigns"


def test_an_existing_path_wins_over_a_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tps_dead").write_text("duration_s = 1.0\n")
    (tmp_path / "tps_dead.toml").write_text("duration_s = 1.0\n")
    assert resolve("scenario", "tps_dead") == Path("tps_dead")
    assert resolve("scenario", "tps_dead.toml") == Path("tps_dead.toml")


@pytest.mark.parametrize("arg", ["nope", "sub/tps_dead.toml", "sub/tps_dead", "tps_dead.yaml"])
def test_neither_a_file_nor_a_name_is_one_line_naming_both(arg, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(BadFileError) as exc:
        resolve("scenario", arg)
    msg = str(exc.value)
    assert msg.startswith(f"{arg}: no such file, nor a shipped scenario")
    assert "tps_dead" in msg and "\n" not in msg


def test_list_names_and_descriptions(capsys):
    assert vecu(["scenario", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    files = shipped_files("scenario")
    assert [ln.split()[0] for ln in lines] == list(files)
    assert all(describe(files[ln.split()[0]]) in ln for ln in lines)
    assert describe(files["tps_dead"]).startswith("TPS dead")
    assert vecu(["campaign", "list", "--names"]) == 0
    assert capsys.readouterr().out.splitlines() == list(shipped_files("campaign"))


def test_show_prints_the_file_to_copy(capsys, tmp_path):
    assert vecu(["scenario", "show", "tps_dead"]) == 0
    text = capsys.readouterr().out
    assert text == shipped_files("scenario")["tps_dead"].read_text(encoding="utf-8")
    assert vecu(["campaign", "show", "tps-kill-latency", "--path"]) == 0
    assert capsys.readouterr().out.strip() == str(shipped_files("campaign")["tps-kill-latency"])
    assert vecu(["campaign", "show", str(tmp_path)]) == 2  # a directory: one line, no traceback
    assert capsys.readouterr().err.startswith(f"vecu: error: {tmp_path}: cannot read")


@pytest.mark.parametrize("argv", [["scenario", "run", "nope"], ["campaign", "run", "nope"]])
def test_run_by_an_unknown_name_is_a_user_error(argv, capsys):
    assert vecu(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vecu: error: nope: no such file, nor a shipped {argv[0]}")


def test_version_comes_from_the_installed_metadata(tmp_path):
    import vecu

    assert vecu.__version__ == version("vecu")
    res = subprocess.run([sys.executable, "-m", "vecu", "--version"], capture_output=True,
                         text=True, cwd=tmp_path, timeout=60, check=False)
    assert res.returncode == 0 and res.stdout == f"vecu {version('vecu')}\n", res


def test_outputs_line_names_what_was_kept_and_only_what_is_missing():
    assert outputs_line(plot=None, log=None, summary=None) == (
        "outputs: add --plot FILE.png --log FILE.blf --summary FILE.json to keep them")
    assert outputs_line(plot=None, log="x.blf", summary="x.json") == (
        "outputs: kept: log x.blf, summary x.json; add --plot FILE.png to keep it")
    assert outputs_line(plot="p.png", log="x.blf", summary="x.json") == (
        "outputs: kept: plot p.png, log x.blf, summary x.json")
