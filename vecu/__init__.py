"""vecu: a virtual ECU gateway for CAN (README.md). `vecu.__version__` is the installed
distribution's version (pyproject.toml is its one source), read on first use."""

from __future__ import annotations


def __getattr__(name: str) -> str:
    if name == "__version__":  # lazily: importing vecu stays free of importlib.metadata
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("vecu")
        except PackageNotFoundError:  # a source tree on sys.path that was never installed
            return "0+unknown"
    raise AttributeError(f"module 'vecu' has no attribute {name!r}")
