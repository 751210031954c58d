"""Shared test fixtures: paths to the repo and to the third-party data beside it."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
THIRDPARTY = REPO.parent / "shared" / "thirdparty"


@pytest.fixture
def thirdparty() -> Path:
    if not THIRDPARTY.is_dir():
        pytest.skip(f"third-party data not found at {THIRDPARTY}")
    return THIRDPARTY


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels_ready() -> None:
    """Under the numba backend, load (or, on a fresh checkout, compile: ~40 s once) every kernel
    before the first test, so that the processes the live tests start find numba's disk cache
    warm instead of each compiling on its own while a test's start-up timeout runs."""
    from vecu.runner import load_kernels

    load_kernels()


@pytest.fixture
def backend_switch():
    """Yields run(fn, backend) -> fn() under that kernel backend (vecu.kernels.using); the
    backend active before the test comes back afterwards, also after a switch inside it."""
    from vecu import kernels

    def run(fn, name):
        with kernels.using(name):
            return fn()

    with kernels.using(kernels.backend()):
        yield run
