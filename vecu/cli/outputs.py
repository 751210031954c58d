"""Output files the user names (--log, --out, --summary, --plot, --junit, --report, --ready-file):
checked before any work, so that a mistake is one line and exit 2, not a traceback after the run.

Every output option is marked by its argparse type (vecu.argtypes.out_file / out_log / out_plot /
out_dir / output(kind, suffix)); `check_output_args` finds them in the parsed arguments and the
command line (vecu.cli.run_command) calls it before any subcommand starts: one check for all.

Each file must be a file name (not a directory) in an existing directory where vecu can create
it, with an allowed suffix; logs a suffix python-can writes (with its package: asammdf for .mf4);
plots a suffix matplotlib writes (no suffix would make matplotlib add '.png' behind the user's
back); a directory (kind 'dir') must be a directory that exists or can be created: its nearest
existing ancestor a writable directory. /proc, /sys and other places where no file can be
created fail the probe (a file created and removed at once: the only test that holds for root).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from vecu.argtypes import OutputPath
from vecu.errors import BadArgumentError, BadFileError

# the kind of a path given to check_outputs by keyword as a plain str (an OutputPath has its own)
LOG_OPTIONS = ("log", "out")       # python-can traces
PLOT_OPTIONS = ("plot",)           # matplotlib figures
DIR_OPTIONS = ("report",)          # directories vecu fills
KERNEL_FS = (Path("/proc"), Path("/sys"), Path("/dev"))  # named as such when the probe fails


def check_output_args(args: argparse.Namespace) -> None:
    """check_outputs for every output option of a parsed command line (its OutputPath values,
    defaults included), named by its dest (the option's long name: tests/cli/test_outputs.py)."""
    check_outputs(**{dest: v for dest, v in sorted(vars(args).items())
                     if isinstance(v, OutputPath)})


def check_outputs(**paths: str | None) -> None:
    """Raise a UserError for the first output that cannot be written; keywords are the option
    names without dashes (log=, out=, summary=, plot=, junit=, ready_file=, report=); None or a
    missing keyword: not asked for. An OutputPath brings its kind; a plain str takes the kind
    its name has above (else 'file'). Creates nothing (a probe file is removed at once)."""
    given = {opt: p for opt, p in paths.items() if p is not None}
    seen: dict[str, str] = {}
    for opt, path in given.items():
        flag = "--" + opt.replace("_", "-")
        if not path.strip():
            raise BadArgumentError(f"{flag}: empty file name")
        kind, suffixes = ((path.kind, path.suffixes) if isinstance(path, OutputPath) else
                          ("dir" if opt in DIR_OPTIONS else "log" if opt in LOG_OPTIONS else
                           "plot" if opt in PLOT_OPTIONS else "file", ()))
        try:
            _check_one(path, flag, kind, suffixes)
        except BadFileError as exc:
            if exc.option is not None or exc.path is None:
                raise
            raise type(exc)(exc.path, exc.problem, option=flag) from None
        if kind == "dir":
            continue
        key = os.path.realpath(path)
        if key in seen:
            raise BadArgumentError(f"{seen[key]} and {flag} name the same file {path}")
        seen[key] = flag


def _check_one(path: str, flag: str, kind: str, suffixes: tuple[str, ...]) -> None:
    if kind == "dir":
        _check_dir(path)
        return
    _check_file(path, flag)
    if suffixes and not path.lower().endswith(tuple(s.lower() for s in suffixes)):
        raise BadFileError(path, f"expected a {' or '.join(suffixes)} file name")
    if kind == "log":
        from vecu.recorder import check_log_path
        check_log_path(path)
    elif kind == "plot":
        check_plot_path(path)


def _check_file(path: str, flag: str) -> None:
    p = Path(path)
    if p.is_dir():
        raise BadFileError(path, f"is a directory ({flag} wants a file name)")
    parent = _nearest_existing(p.absolute().parent)
    if not parent.is_dir():
        raise BadFileError(path, f"{parent} is a file, not a directory")
    if parent != p.absolute().parent:
        raise BadFileError(path, "directory does not exist")
    if p.exists():
        try:
            with open(p, "ab"):  # append: checks write access, changes nothing
                pass
        except OSError as exc:
            raise BadFileError(path, f"cannot write: {exc.strerror}") from None
    else:
        _probe(parent, path)


def _nearest_existing(p: Path) -> Path:
    """p or its nearest ancestor that exists (where a mkdir would start)."""
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_dir(path: str) -> None:
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BadFileError(path, "not a directory")
    existing = _nearest_existing(p.absolute())
    if not existing.is_dir():
        raise BadFileError(path, f"cannot create directory: {existing} is a file, not a "
                                 "directory")
    _probe(existing, path)


def _probe(directory: Path, path: str) -> None:
    """Create and remove a file in directory: the only test of write access that holds for root
    and for file systems such as /proc and /sys."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".vecu-probe-")
    except OSError as exc:
        special = next((k for k in KERNEL_FS if directory == k or k in directory.parents), None)
        why = f"{special} is a kernel file system" if special else exc.strerror
        raise BadFileError(path, f"cannot create a file in {directory} ({why})") from None
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


def _outputs(args: argparse.Namespace) -> list[tuple[str, OutputPath]]:
    return [(dest, v) for dest, v in sorted(vars(args).items()) if isinstance(v, OutputPath)]


def _state(path: OutputPath) -> object:
    """What tells a change of an output: a file's (mtime, size), a directory's files' ones."""
    p = Path(path)
    try:
        if path.kind == "dir":
            return {f: (s.st_mtime_ns, s.st_size) for f in p.rglob("*")
                    if f.is_file() and (s := f.stat())} if p.is_dir() else None
        st = p.stat()
        return (st.st_mtime_ns, st.st_size)
    except OSError:
        return None


def output_state(args: argparse.Namespace) -> dict[str, object]:
    """The state of every output of a parsed command line before it runs (report_interrupted
    tells what was written since)."""
    return {dest: _state(v) for dest, v in _outputs(args)}


def report_interrupted(args: argparse.Namespace, before: dict[str, object],
                       done: str | None = None, summary: dict | None = None) -> int:
    """Ctrl-C on any command (vecu.cli.run_command): the partial summary written where --summary
    asked for it (marked "interrupted": true), one line saying how far the command came and
    which outputs it kept (those changed since `before`, output_state()), exit code 130."""
    import json

    path = getattr(args, "summary", None)
    if summary is not None and path:
        Path(path).write_text(json.dumps({**summary, "interrupted": True}, indent=2) + "\n")
    kept = []
    for dest, value in _outputs(args):
        now, then = _state(value), before.get(dest)
        if now is None or now == then:
            continue
        flag = "--" + dest.replace("_", "-")
        if isinstance(now, dict):
            old = then if isinstance(then, dict) else {}
            n = sum(1 for f, st in now.items() if old.get(f) != st)
            kept.append(f"{flag} {value} ({n} file{'s' if n != 1 else ''})")
        else:
            kept.append(f"{flag} {value}" + (" (partial)" if dest == "summary" else ""))
    print(f"vecu: interrupted{f' after {done}' if done else ''}; "
          + (f"kept {', '.join(kept)}" if kept else "nothing written"), file=sys.stderr, flush=True)
    return 130
