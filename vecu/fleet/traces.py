"""The traces of a fleet: files, directories (every file python-can reads, recursively) and
globs, in a fixed order, each with a unique name for its outputs."""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path

from vecu.errors import BadArgumentError
from vecu.replay.source import reader_formats

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def _is_trace(path: Path) -> bool:
    """A file whose suffix names a format python-can reads (a `.gz` around one included)."""
    suffixes = [s.lower().lstrip(".") for s in path.suffixes]
    if suffixes and suffixes[-1] == "gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] in reader_formats()


def expand(args: list[str]) -> list[str]:
    """Every trace the arguments name, each once, sorted within a directory or glob and in
    argument order across them; a name that matches nothing is a user error."""
    out: list[str] = []
    for arg in args:
        path = Path(arg)
        if path.is_dir():
            found = sorted(str(p) for p in path.rglob("*") if p.is_file() and _is_trace(p))
            if not found:
                raise BadArgumentError(f"{arg}: no trace files in this directory (suffixes "
                                       f"{', '.join(reader_formats())}, also .gz)")
        elif path.exists():
            found = [arg]
        elif glob.has_magic(arg):
            found = sorted(p for p in glob.glob(arg, recursive=True) if Path(p).is_file())
            if not found:
                raise BadArgumentError(f"{arg}: matches no file")
        else:
            raise BadArgumentError(f"{arg}: no such file or directory")
        out += [p for p in found if p not in out]
    return out


def trace_names(paths: list[str]) -> list[str]:
    """A file name per trace for its outputs: its path below the traces' common directory with
    every run of other characters than letters, digits, '.', '_' and '-' as '_' (e.g.
    `day1/drive.blf` -> `day1_drive.blf`); a clash gets `-2`, `-3`..."""
    absolute = [os.path.abspath(p) for p in paths]
    common = os.path.commonpath([os.path.dirname(p) for p in absolute]) if absolute else ""
    names: list[str] = []
    for p in absolute:
        stem = _UNSAFE.sub("_", os.path.relpath(p, common)).strip("._") or "trace"
        name, k = stem, 2
        while name in names:
            name, k = f"{stem}-{k}", k + 1
        names.append(name)
    return names
