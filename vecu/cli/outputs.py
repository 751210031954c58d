"""Output files the user names (--log, --out, --summary, --plot, --junit, --report, --ready-file):
checked before any work, so that a mistake is one line and exit 2, not a traceback after the run.

Each must name a file (not a directory) in an existing directory where vecu can create it;
logs a suffix python-can writes (with its package: asammdf for .mf4); plots a suffix matplotlib
writes (no suffix would make matplotlib add '.png' behind the user's back); a report directory
must be a directory that exists or can be created.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from vecu.errors import BadArgumentError, BadFileError

LOG_OPTIONS = ("log", "out")       # python-can traces
PLOT_OPTIONS = ("plot",)           # matplotlib figures
DIR_OPTIONS = ("report",)          # directories vecu fills


def check_outputs(**paths: str | None) -> None:
    """Raise a UserError for the first output that cannot be written; keywords are the option
    names without dashes (log=, out=, summary=, plot=, junit=, ready_file=, report=); None or a
    missing keyword: not asked for. Creates nothing (a probe file is removed at once)."""
    given = {opt: p for opt, p in paths.items() if p is not None}
    seen: dict[str, str] = {}
    for opt, path in given.items():
        flag = "--" + opt.replace("_", "-")
        if not path.strip():
            raise BadArgumentError(f"{flag}: empty file name")
        if opt in DIR_OPTIONS:
            _check_dir(path)
            continue
        _check_file(path, flag)
        key = os.path.realpath(path)
        if key in seen:
            raise BadArgumentError(f"{seen[key]} and {flag} name the same file {path}")
        seen[key] = flag
        if opt in LOG_OPTIONS:
            from vecu.recorder import check_log_path
            check_log_path(path)
        elif opt in PLOT_OPTIONS:
            check_plot_path(path)


def _check_file(path: str, flag: str) -> None:
    p = Path(path)
    if p.is_dir():
        raise BadFileError(path, f"is a directory ({flag} wants a file name)")
    parent = p.resolve().parent
    if not parent.is_dir():
        raise BadFileError(path, "directory does not exist")
    if p.exists():
        try:
            with open(p, "ab"):  # append: checks write access, changes nothing
                pass
        except OSError as exc:
            raise BadFileError(path, f"cannot write: {exc.strerror}") from None
    else:
        _probe(parent, path)


def _check_dir(path: str) -> None:
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BadFileError(path, "not a directory")
    existing = p.resolve()
    while not existing.exists():  # the nearest existing ancestor: where mkdir starts
        existing = existing.parent
    if not existing.is_dir():
        raise BadFileError(path, f"cannot create directory: {existing} is not a directory")
    _probe(existing, path)


def _probe(directory: Path, path: str) -> None:
    """Create and remove a file in directory: the only test of write access that holds for root
    and for file systems such as /proc."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".vecu-probe-")
    except OSError as exc:
        raise BadFileError(path, f"cannot create a file in {directory} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(name)


def check_plot_path(path: str) -> None:
    """A suffix matplotlib writes here (png, pdf, svg, …; pgf only with its TeX engine)."""
    import matplotlib
    from matplotlib.backend_bases import FigureCanvasBase

    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    suffix = Path(path).suffix.lower().lstrip(".")
    if not suffix:
        raise BadFileError(path, f"no suffix to tell the plot format (e.g. {path}.png; "
                                 f"matplotlib writes {', '.join(formats)})")
    if suffix not in formats:
        raise BadFileError(path, f"matplotlib cannot write '.{suffix}' plots (it writes "
                                 f"{', '.join(formats)})")
    if suffix == "pgf":
        import shutil

        tex = matplotlib.rcParams["pgf.texsystem"]
        if shutil.which(tex) is None:
            raise BadFileError(path, f".pgf plots need {tex}, which is not installed")
