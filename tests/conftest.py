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


KERNEL_BACKENDS = ("python", "numba")


@pytest.fixture(params=KERNEL_BACKENDS)
def backend(request):
    """Each kernel backend in turn, active for the test (vecu.kernels.using; the one active
    before comes back afterwards); "numba" is skipped where numba is not installed."""
    from vecu import kernels

    if request.param == "numba" and not kernels.numba_available():
        pytest.skip("numba not installed")
    with kernels.using(request.param) as name:
        yield name


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
