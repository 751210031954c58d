"""What a wheel carries and what CI proves of it: every subcommand tried by .ci/wheel-smoke,
every data file under vecu/ declared package data, every `vecu[extra]` a hint names defined."""

from __future__ import annotations

import argparse
import fnmatch
import re
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

from vecu.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
SMOKE = (REPO / ".ci" / "wheel-smoke").read_text()
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return {name: child for action in parser._actions
            if isinstance(action, argparse._SubParsersAction)
            for name, child in action.choices.items()}


def _loop_words(var: str) -> list[str]:
    """The words of the script's `for VAR in ...; do` list (quoted strings kept whole)."""
    body = re.search(rf"for {var} in (.*?); do", SMOKE, re.DOTALL).group(1).replace("\\\n", " ")
    return [quoted or word for quoted, word in re.findall(r'"([^"]+)"|(\S+)', body)]


def _run_steps() -> list[str]:
    """The `vecu …` command line of every step that is not a --help."""
    return [m for m in re.findall(r"^step .*?\b(vecu [^\n]*)", SMOKE, re.MULTILINE)
            if "--help" not in m]


def test_every_subcommand_has_help_and_a_run_in_the_wheel_smoke():
    top = _subparsers(build_parser())
    helped = set(_loop_words("cmd"))
    nested_helped = set(_loop_words("nested"))
    runs = _run_steps()
    assert len(top) >= 13
    for name, parser in top.items():
        assert name in helped, f".ci/wheel-smoke: no `vecu {name} --help`"
        assert any(re.match(rf"vecu {name}\b", r) for r in runs), \
            f".ci/wheel-smoke: no smoke run of `vecu {name}`"
        for sub in _subparsers(parser):
            assert f"{name} {sub}" in nested_helped, f".ci/wheel-smoke: no `vecu {name} {sub} --help`"


def test_the_smoke_runs_shipped_files_by_name_from_outside_the_checkout():
    runs = _run_steps()
    assert "vecu scenario run tps_dead --junit junit.xml" in runs
    assert any(r.startswith("vecu campaign run tps-kill-latency --runs 2") for r in runs)
    assert 'cd "$WORK/user"' in SMOKE and "pip install --quiet \"${WHEELS[0]}\"" in SMOKE
    assert "-e " not in SMOKE  # the wheel, never an editable install
    assert ".ci/wheel-smoke" in (REPO / ".ci" / "run").read_text()


def test_packages_are_found_not_listed():
    setuptools = PYPROJECT["tool"]["setuptools"]
    assert "packages" not in setuptools or "find" in setuptools["packages"]
    assert setuptools["packages"]["find"]["include"] == ["vecu", "vecu.*"]


def test_every_data_file_under_the_package_is_package_data():
    """A file a subcommand reads at run time ships in the wheel only when a package-data glob
    names it: a new kind of file under vecu/ must be added there."""
    globs = PYPROJECT["tool"]["setuptools"]["package-data"]
    pkg = REPO / "vecu"
    data = [p for p in pkg.rglob("*") if p.is_file() and p.suffix not in (".py", ".pyc", ".nbi",
                                                                            ".nbc")
            and "__pycache__" not in p.parts]
    assert len(data) >= 22  # 2 DBCs, 17 scenarios, 3 campaigns
    for path in data:
        rel = path.relative_to(REPO)
        covered = any(fnmatch.fnmatch(str(rel), str(Path(*package.split("."), pattern)))
                      for package, patterns in globs.items() for pattern in patterns)
        assert covered, f"{rel}: not matched by [tool.setuptools.package-data]"


def test_every_extra_a_hint_names_exists():
    extras = set(PYPROJECT["project"]["optional-dependencies"])
    files = [*(REPO / "vecu").rglob("*.py"), *(REPO / "docs").glob("*.md"), REPO / "README.md"]
    named = {(f.relative_to(REPO), m) for f in files
             for m in re.findall(r"vecu\[([\w,-]+)\]", f.read_text(encoding="utf-8"))}
    assert named
    unknown = [f"{f}: vecu[{m}]" for f, m in named if not set(m.split(",")) <= extras]
    assert not unknown, unknown
