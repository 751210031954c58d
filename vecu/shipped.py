"""Scenarios and campaigns shipped with vecu (package data in vecu/data/), found by name from any
directory: `vecu scenario run tps_dead`, `vecu campaign run tps-kill-latency`. A path that exists
wins over a name, so a user's own file of the same name is never shadowed."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from vecu.errors import BadFileError
from vecu.tomlfile import read_toml

FOLDERS = {"scenario": "scenarios", "campaign": "campaigns"}  # kind -> folder in vecu/data/
SUFFIX = ".toml"


def shipped_files(kind: str) -> dict[str, Path]:
    """Name (file stem) -> file of every shipped scenario or campaign, sorted by name."""
    # wheels and editable installs unpack package data as files: a real path to print and read
    folder = Path(str(resources.files("vecu.data").joinpath(FOLDERS[kind])))
    return {p.stem: p for p in sorted(folder.glob(f"*{SUFFIX}"))}


def describe(path: Path) -> str:
    """The file's `description` (empty when it has none)."""
    return str(read_toml(path).get("description", ""))


def resolve(kind: str, arg: str) -> Path:
    """The file a FILE-or-NAME argument means: an existing path as given, else the shipped file
    of that name (with or without .toml); anything else is one line naming both tries."""
    path = Path(arg)
    if path.exists():
        return path  # a path wins; a directory or bad file is its reader's one-line error
    files = shipped_files(kind)
    stem = arg.removesuffix(SUFFIX)
    if path.name == arg and stem in files:  # a bare name, no directory part
        return files[stem]
    raise BadFileError(arg, f"no such file, nor a shipped {kind} of that name (shipped: "
                            f"{', '.join(files) or 'none'}; `vecu {kind} list`)")
