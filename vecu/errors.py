"""vecu's one error tree (imports no other vecu module).

    VecuError
    └── UserError                    a user's mistake: `vecu: error: <message>`, exit code 2
        ├── BadArgumentError     a bad option or argument value (also a ValueError)
        ├── ConfigError          an impossible configuration or setting (also a ValueError)
        ├── BadFileError         a file the user named cannot be read, used or written
        └── UnavailableError     something asked for is not available here (bus, package)

Anything else that escapes the command line is a bug: a traceback and exit code 1. The
ValueError bases keep `except ValueError` in library callers working for validation errors.

    KeyboardInterrupt
    └── Interrupted                  Ctrl-C part-way, with what was done: `vecu: interrupted …`
                                     (what was kept), exit code 130
"""

from __future__ import annotations

import os


class VecuError(Exception):
    """Base of every error vecu raises on purpose."""


class UserError(VecuError):
    """A user's mistake; the command line reports it as one line `vecu: error: …`, exit 2."""


class BadArgumentError(UserError, ValueError):
    """A bad option or argument value (a time outside the run, an unknown name, …)."""


class ConfigError(UserError, ValueError):
    """A configuration or environment setting that cannot work (e.g. VECU_KERNELS=cuda)."""


class BadFileError(UserError):
    """A file the user named cannot be read, used or written; str() is "PATH: problem", or
    "--OPTION PATH: problem" when the option that named it is known."""

    def __init__(self, path: str | os.PathLike[str] | None, problem: str,
                 option: str | None = None) -> None:
        self.path = None if path is None else os.fspath(path)
        self.problem = problem
        self.option = option
        where = self.path if option is None or path is None else f"{option} {self.path}"
        super().__init__(problem if where is None else f"{where}: {problem}")

    def __reduce__(self) -> tuple:  # picklable across processes (scenario --jobs)
        return type(self), (self.path, self.problem, self.option)


class UnavailableError(UserError):
    """Something asked for is not available on this machine: a bus, an optional package."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) stopped a command part-way, and it has a result so far: `done` says how
    far it came ("12.345 of 60 s simulated"); `summary` is its partial summary as --summary
    writes it (None: the command wrote its own). Still a KeyboardInterrupt for library callers;
    the command line writes the summary, says in one line what was kept and exits 130."""

    def __init__(self, done: str, summary: dict | None = None) -> None:
        super().__init__(done)
        self.done = done
        self.summary = summary


__all__ = ["BadArgumentError", "BadFileError", "ConfigError", "Interrupted", "UnavailableError",
           "UserError", "VecuError"]
