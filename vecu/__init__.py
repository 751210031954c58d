"""vecu: a virtual ECU gateway for CAN (README.md). `vecu.__version__` is the installed
distribution's version (pyproject.toml is its one source), read on first use;
`vecu.simulate(...)` runs what `vecu run` runs and returns its typed summary
(vecu.simulation, docs/python.md), imported on first use."""

from __future__ import annotations

from typing import Any

__all__ = ["run_config", "simulate"]


def __getattr__(name: str) -> Any:
    if name in ("simulate", "run_config"):  # lazily: `import vecu` stays light
        from vecu import simulation

        return getattr(simulation, name)
    if name == "__version__":  # lazily: importing vecu stays free of importlib.metadata
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("vecu")
        except PackageNotFoundError:  # a source tree on sys.path that was never installed
            return "0+unknown"
    raise AttributeError(f"module 'vecu' has no attribute {name!r}")
