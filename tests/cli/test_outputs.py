"""Output files (vecu/cli/outputs.py): a directory, an unwritable place, a format matplotlib or
python-can cannot write, or no suffix at all is one line and exit 2 BEFORE the run (issue 14
item 7), in every subcommand that writes files: run, replay, plant, ecu, scenario."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from vecu.cli import build_parser, main, run_command
from vecu.cli.outputs import check_outputs
from vecu.errors import BadArgumentError, BadFileError, UnavailableError, UserError

ENV = {**os.environ, "VECU_KERNELS": "python"}


@pytest.mark.parametrize("kwargs,needle", [
    ({"summary": "{d}"}, "is a directory (--summary wants a file name)"),
    ({"junit": "{d}"}, "is a directory"),
    ({"summary": "/proc/x.json"}, "cannot create a file in /proc"),
    ({"summary": "{d}/missing/x.json"}, "directory does not exist"),
    ({"plot": "{d}/run.xyz"}, "matplotlib cannot write '.xyz' plots"),
    ({"plot": "{d}/run"}, "no suffix to tell the plot format (e.g. {d}/run.png"),
    ({"plot": "{d}"}, "is a directory (--plot wants a file name)"),
    ({"log": "{d}/x.bogus"}, "cannot write log: unknown format '.bogus'"),
    ({"out": "{d}/x"}, "cannot write log: no suffix"),
    ({"log": "{d}/x.blf.gz"}, "cannot write log: no compressed format"),
    ({"report": "{d}/file.txt"}, "not a directory"),
    ({"report": "/proc/vecu-report"}, "cannot create a file in /proc"),
])
def test_bad_output_is_a_user_error_naming_the_file(kwargs, needle: str, tmp_path: Path) -> None:
    (tmp_path / "file.txt").write_text("keep")
    kwargs = {k: v.format(d=tmp_path) for k, v in kwargs.items()}
    with pytest.raises(UserError) as exc:
        check_outputs(**kwargs)
    assert needle.format(d=tmp_path) in str(exc.value)
    assert isinstance(exc.value, BadFileError) and len(str(exc.value).splitlines()) == 1


def test_good_outputs_pass_and_nothing_is_created_or_changed(tmp_path: Path) -> None:
    (tmp_path / "old.json").write_text("keep")
    check_outputs(log=str(tmp_path / "a.blf"), out=str(tmp_path / "b.log.gz"),
                  summary=str(tmp_path / "old.json"), plot=str(tmp_path / "p.svg"),
                  junit=str(tmp_path / "j.xml"), ready_file=None,
                  report=str(tmp_path / "new" / "report"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json"]
    assert (tmp_path / "old.json").read_text() == "keep"


def test_two_outputs_on_one_file(tmp_path: Path) -> None:
    with pytest.raises(BadArgumentError, match="--summary and --plot name the same file"):
        check_outputs(summary=str(tmp_path / "x.png"), plot=str(tmp_path / "x.png"))


def test_mf4_without_asammdf_names_the_extra(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "asammdf", None)  # `import asammdf` raises ImportError
    with pytest.raises(UnavailableError) as exc:
        check_outputs(log=str(tmp_path / "x.mf4"))
    assert str(exc.value) == (f"{tmp_path / 'x.mf4'}: writing .mf4 needs the asammdf package: "
                              "pip install 'vecu[mf4]'")


# ------------------------------------------------------------------ every subcommand, for real
@pytest.fixture(scope="module")
def place(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory with a two-frame candump trace and a short scenario."""
    d = tmp_path_factory.mktemp("outputs")
    (d / "t.log").write_text("(0.000000) vecu 100#F4008813\n(0.001000) vecu 100#F4008813\n")
    (d / "s.toml").write_text('name = "short"\nduration_s = 0.2\n')
    (d / "sub").mkdir()
    return d


CASES = [
    ["run", "--duration", "0.3", "--summary", "sub"],
    ["run", "--duration", "0.3", "--summary", "/proc/x.json"],
    ["run", "--duration", "0.3", "--plot", "run.xyz"],
    ["run", "--duration", "0.3", "--plot", "sub"],
    ["run", "--duration", "0.3", "--plot", "runplot"],  # would be runplot.png behind the back
    ["replay", "t.log", "--plot", "sub"],
    ["replay", "t.log", "--summary", "/proc/x.json"],
    ["replay", "t.log", "--plot", "replayplot"],
    ["plant", "--duration", "0.3", "--summary", "/proc/x.json"],
    ["ecu", "--duration", "0.3", "--sync-timeout", "0", "--summary", "sub"],
    ["scenario", "run", "s.toml", "--junit", "sub"],
    ["scenario", "run", "s.toml", "--junit", "/proc/x.xml"],
]


def _one_line(rc: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("argv", CASES, ids=[" ".join(a) for a in CASES])
def test_bad_output_fails_before_the_run_in_one_line(argv: list[str], place: Path, capsys,
                                                      monkeypatch) -> None:
    monkeypatch.chdir(place)
    before = sorted(p.name for p in place.iterdir())
    line = _one_line(main(argv), capsys.readouterr().err)
    assert line.startswith(f"vecu: error: {argv[-2]} {argv[-1]}: "), line
    assert capsys.readouterr().out == ""  # no run, no summary
    assert sorted(p.name for p in place.iterdir()) == before  # nothing written


@pytest.mark.parametrize("argv", [CASES[4], CASES[7], CASES[10]], ids=["run", "replay", "scenario"])
def test_in_a_real_process_too(argv: list[str], place: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                         env=ENV, cwd=place, timeout=120, check=False)
    assert _one_line(res.returncode, res.stderr).startswith(f"vecu: error: {argv[-2]} {argv[-1]}: ")
    assert res.stdout == ""


@pytest.mark.parametrize("argv", [["run", "--duration", "0.3", "--log", "x.mf4"],
                                  ["replay", "t.log", "--out", "x.mf4"]], ids=["run", "replay"])
def test_mf4_without_asammdf_fails_before_the_run(argv: list[str], place: Path,
                                                  tmp_path: Path) -> None:
    """Issue 14 item 9: `vecu run --log x.mf4` without asammdf was a NotImplementedError traceback
    from python-can after the set-up. Here asammdf is hidden by a module that cannot be imported."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "asammdf.py").write_text("raise ImportError(\"No module named 'asammdf'\")\n")
    env = {**ENV, "PYTHONPATH": os.pathsep.join(p for p in (str(hide), ENV.get("PYTHONPATH")) if p)}
    res = subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                         env=env, cwd=place, timeout=120, check=False)
    assert _one_line(res.returncode, res.stderr) == (
        "vecu: error: x.mf4: writing .mf4 needs the asammdf package: pip install 'vecu[mf4]'")
    assert res.stdout == "" and not (place / "x.mf4").exists()


# ------------------------------------------- every output option of every subcommand, by table
OUTPUT_NAMES = ("--out", "--out-dir", "--log", "--summary", "--plot", "--junit", "--report",
                "--ready-file", "--html", "--csv", "--save", "--dump")  # names that write files


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) for the top parser and every (nested) subcommand's parser."""
    yield path, parser
    seen: set[int] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                if id(child) not in seen:  # aliases share a parser
                    seen.add(id(child))
                    yield from _parsers(child, (*path, name))


def _output_options() -> list[tuple[tuple[str, ...], argparse.Action]]:
    return [(path, a) for path, p in _parsers(build_parser()) for a in p._actions
            if getattr(a.type, "output_kind", None) is not None]


OUTPUTS = _output_options()


def _filler(action: argparse.Action) -> str:
    """A value argparse takes for a required positional or option (the check runs first, so
    it need not name anything real)."""
    if action.choices:
        return str(next(iter(action.choices)))
    for value in ("x", "1"):
        try:
            (action.type or str)(value)
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
        return value
    raise AssertionError(f"no filler value for {action.dest}")


def _argv(path: tuple[str, ...], action: argparse.Action, value: str) -> list[str]:
    parser = dict(_parsers(build_parser()))[path]
    argv = list(path)
    for a in parser._actions:
        if a.option_strings and a.required:
            argv += [a.option_strings[0], _filler(a)]
        elif not a.option_strings and not isinstance(a, argparse._SubParsersAction):
            argv.append(_filler(a))
    return [*argv, action.option_strings[-1], value]


def _good_name(action: argparse.Action) -> str:
    suffixes = getattr(action.type, "output_suffixes", ())
    kind = action.type.output_kind
    return "out" + (suffixes[0] if suffixes else {"log": ".blf", "plot": ".png",
                                                   "file": ".json"}.get(kind, ""))


def test_the_table_covers_every_subcommand_that_writes() -> None:
    """Every option named like an output is marked as one (its type), under its own name (the
    check names an option by its dest); the table is not empty where files are written."""
    for path, p in _parsers(build_parser()):
        for a in p._actions:
            if any(o in OUTPUT_NAMES for o in a.option_strings):
                assert getattr(a.type, "output_kind", None), f"vecu {' '.join(path)} {a.option_strings}"
    for path, a in OUTPUTS:  # an output is an option (a positional would be named --DEST)
        assert "--" + a.dest.replace("_", "-") in a.option_strings, (path, a.dest)
    commands = {path[0] for path, _ in OUTPUTS}
    assert {"run", "replay", "plant", "ecu", "gateway", "restbus", "scenario", "campaign",
            "figures", "identify", "excite", "a2l"} <= commands


def _bad_cases(kind: str, good: str) -> list[tuple[str, str]]:
    """(path template, expected problem) per kind; {d} a directory, {f} a file."""
    if kind == "dir":
        return [("{f}", "not a directory"),
                ("{f}/camp", "is a file, not a directory"),
                ("/proc/vecu-out", "cannot create a file in /proc (/proc is a kernel file system)"),
                ("/sys/vecu-out", "cannot create a file in /sys (/sys is a kernel file system)")]
    return [("{d}", "is a directory"),
            ("{f}/" + good, "is a file, not a directory"),
            ("{d}/missing/" + good, "directory does not exist"),
            ("/proc/" + good, "cannot create a file in /proc (/proc is a kernel file system)"),
            ("/sys/" + good, "cannot create a file in /sys (/sys is a kernel file system)")]


@pytest.mark.parametrize("path,action", OUTPUTS,
                         ids=[f"{' '.join(p)} {a.option_strings[-1]}" for p, a in OUTPUTS])
def test_every_output_option_rejects_bad_places_before_any_work(
        path: tuple[str, ...], action: argparse.Action, tmp_path: Path, capsys) -> None:
    """Each bad place: exit 2, one line naming the option, the path and the problem, and the
    subcommand never called; a good place passes to the subcommand. Nothing is created."""
    d, f = tmp_path / "dir", tmp_path / "file.blf"
    d.mkdir()
    f.write_text("keep")
    calls: list[str] = []
    good = _good_name(action)
    flag = action.option_strings[-1]
    for template, problem in _bad_cases(action.type.output_kind, good):
        value = template.format(d=d, f=f)
        args = build_parser().parse_args(_argv(path, action, value))
        args.func = lambda a: calls.append("ran")
        rc = run_command(args)
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1, (value, err)
        assert err.startswith(f"vecu: error: {flag} {value}: ") and problem in err, err
    assert calls == []
    args = build_parser().parse_args(_argv(path, action, str(tmp_path / good)))
    args.func = lambda a: calls.append("ran")
    assert run_command(args) == 0 and calls == ["ran"], capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "file.blf"]
    assert list(d.iterdir()) == [] and f.read_text() == "keep"


ISSUE_CASES = [
    (["campaign", "run", "tps-kill-latency", "--out", "x.blf"], "--out x.blf: not a directory"),
    (["campaign", "run", "tps-kill-latency", "--out", "x.blf/camp"], ("--out x.blf/camp: cannot "
     "create directory: {d}/x.blf is a file")),
    (["campaign", "run", "tps-kill-latency", "--out", "/sys/camp"], ("--out /sys/camp: cannot "
     "create a file in /sys")),
    (["figures", "--out", "x.blf/figs"], "--out x.blf/figs: cannot create directory"),
    (["identify", "throttle", "x.blf", "--out", "/proc/p.toml"], ("--out /proc/p.toml: cannot "
     "create a file in /proc")),
]


@pytest.mark.parametrize("argv,needle", ISSUE_CASES, ids=[" ".join(a) for a, _ in ISSUE_CASES])
def test_first_contact_cases_in_a_real_process(argv: list[str], needle: str,
                                               tmp_path: Path) -> None:
    """As a new user typed them: one line and exit 2 before the Dask cluster or the fit."""
    (tmp_path / "x.blf").write_bytes(b"")
    res = subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                         env=ENV, cwd=tmp_path, timeout=120, check=False)
    assert _one_line(res.returncode, res.stderr).startswith(
        "vecu: error: " + needle.format(d=tmp_path.resolve()))
    assert res.stdout == "" and sorted(p.name for p in tmp_path.iterdir()) == ["x.blf"]
