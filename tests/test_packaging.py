"""What a wheel carries and what CI proves of it: every subcommand tried by .ci/wheel-smoke,
every data file under vecu/ declared package data, every `vecu[extra]` a hint names defined."""

from __future__ import annotations

import argparse
import fnmatch
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

import pytest

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
    """setup.py finds every package under vecu/ and adds vecu.dbc, which pyproject.toml maps to
    the top-level dbc/ (the one place a package list is written)."""
    setuptools = PYPROJECT["tool"]["setuptools"]
    assert "packages" not in setuptools
    assert setuptools["package-dir"] == {"vecu.dbc": "dbc"}
    setup_py = (REPO / "setup.py").read_text()
    assert 'find_namespace_packages(include=["vecu", "vecu.*"])' in setup_py
    assert '"vecu.dbc"' in setup_py


def test_every_data_file_is_package_data():
    """A file a subcommand reads at run time ships in the wheel only when a package-data glob
    names it (in its package's folder, dbc/ for vecu.dbc): a new kind of file must be added."""
    setuptools = PYPROJECT["tool"]["setuptools"]
    globs, folders = setuptools["package-data"], setuptools["package-dir"]
    data = [p for folder in (REPO / "vecu", REPO / "dbc") for p in folder.rglob("*")
            if p.is_file() and p.suffix not in (".py", ".pyc", ".nbi", ".nbc")
            and "__pycache__" not in p.parts]
    assert len(data) >= 27  # 2 DBCs, 19 scenarios and their 3 companions, 3 campaigns
    for path in data:
        rel = path.relative_to(REPO)
        covered = any(
            fnmatch.fnmatch(str(rel), str(Path(folders.get(package, package.replace(".", "/")),
                                               pattern)))
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


_BUILD = """
import sys, tarfile
from pathlib import Path
from setuptools import build_meta
out = Path(sys.argv[1])
sdist = out / build_meta.build_sdist(str(out))
with tarfile.open(sdist) as tar:
    tar.extractall(out / "src", **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
(unpacked,) = (out / "src").iterdir()
import os
os.chdir(unpacked)
print(out / build_meta.build_wheel(str(out)))
"""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """vecu's wheel built as `python -m build` does (the sdist, then the wheel from it), from a
    copy of the checkout's build inputs so that nothing is written into the checkout (~10 s)."""
    pytest.importorskip("setuptools", minversion="77")
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("dist")
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    for name in ("vecu", "dbc"):
        shutil.copytree(REPO / name, src / name, ignore=ignore)
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE", "MANIFEST.in"):
        shutil.copy(REPO / name, src / name)
    done = subprocess.run([sys.executable, "-c", _BUILD, str(out)], cwd=src, capture_output=True,
                          text=True, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return Path(done.stdout.strip().splitlines()[-1])


def test_the_wheel_ships_the_top_level_dbcs_as_vecu_dbc(wheel, tmp_path):
    """dbc/ is the DBCs' one source (no copy under vecu/); the wheel carries them at vecu/dbc/,
    where an installed vecu loads them by name from outside any checkout."""
    assert not (REPO / "vecu" / "dbc").exists()
    sources = sorted(p.name for p in (REPO / "dbc").glob("*.dbc"))
    assert sources == ["vecu.dbc", "vecu_truth.dbc"]
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
        assert sorted(n for n in names if n.startswith("vecu/dbc/")) == \
            [f"vecu/dbc/{s}" for s in sources]
        for s in sources:
            assert whl.read(f"vecu/dbc/{s}") == (REPO / "dbc" / s).read_bytes()
        whl.extractall(tmp_path / "site")
    assert not any(n.startswith("dbc/") for n in names)
    probe = ("from vecu.codec import DEFAULT_DBC, TRUTH_DBC, builtin_dbc_path, load_database; "
             "p = builtin_dbc_path(); db = load_database([p, builtin_dbc_path(TRUTH_DBC)]); "
             "print(p); print(db.get_message_by_name('ECU_ThrottleEstimate').frame_id)")
    done = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True,
                          text=True, check=False,
                          env={**os.environ, "PYTHONPATH": str(tmp_path / "site")})
    assert done.returncode == 0, done.stderr[-3000:]
    path, frame_id = done.stdout.split()
    assert Path(path) == tmp_path / "site" / "vecu" / "dbc" / "vecu.dbc"
    assert int(frame_id) == 0x200
