"""Shared test fixtures: paths to the repo and to the third-party data beside it; under
pytest-xdist, tests that pace processes on the wall clock run alone (see `wall_clock_alone`)."""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
THIRDPARTY = REPO.parent / "shared" / "thirdparty"


@pytest.fixture
def repo_root() -> Path:
    return REPO


@pytest.fixture
def thirdparty() -> Path:
    if not THIRDPARTY.is_dir():
        pytest.skip(f"third-party data not found at {THIRDPARTY}")
    return THIRDPARTY


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test file named *live* starts processes paced on the wall clock: mark it `alone`."""
    for item in items:
        if "live" in item.path.name:
            item.add_marker(pytest.mark.alone)


@contextlib.contextmanager
def _locked(path: Path, mode: int) -> Iterator[None]:
    with path.open("a") as f:
        fcntl.flock(f, mode)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@pytest.fixture(autouse=True)
def wall_clock_alone(request: pytest.FixtureRequest,
                     tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Under pytest-xdist (`-n`), a test marked `alone` (live processes, wall-clock figures) runs
    while no other worker runs a test: it holds the workers' lock exclusively, every other test
    holds it shared. A turnstile taken before either lets a waiting `alone` test in first."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    shared = tmp_path_factory.getbasetemp().parent  # one folder for all workers of this run
    alone = request.node.get_closest_marker("alone") is not None
    mode = fcntl.LOCK_EX if alone else fcntl.LOCK_SH
    turnstile = _locked(shared / "alone.turnstile", fcntl.LOCK_EX)
    turnstile.__enter__()
    try:
        lock = _locked(shared / "alone.lock", mode)
        lock.__enter__()
    finally:
        turnstile.__exit__(None, None, None)
    try:
        yield
    finally:
        lock.__exit__(None, None, None)


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


class BackendCache:
    """Results computed once per kernel backend (and key) and shared by a module's tests."""

    def __init__(self) -> None:
        self._done: dict = {}

    def get(self, key, fn):
        """fn() under the active backend, computed on the first call for (backend, key)."""
        from vecu import kernels

        k = (kernels.backend(), key)
        if k not in self._done:
            self._done[k] = fn()
        return self._done[k]

    def reference(self, key, fn):
        """fn() under the python backend (the reference the other backends are held to)."""
        from vecu import kernels

        with kernels.using("python"):
            return self.get(key, fn)


@pytest.fixture(scope="module")
def per_backend() -> BackendCache:
    """A module's BackendCache (expensive runs done once per backend, the reference once)."""
    return BackendCache()


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


@pytest.fixture
def plant_rig():
    """make(channel, with_speed=False) -> (codec, plant node, tester bus, injector): a throttle
    plant (seeded streams 'i', 'p', 'f'), optionally with the longitudinal part, on a virtual bus
    with a tester bus beside it; both buses shut down after the test."""
    from vecu.bus import open_bus
    from vecu.codec import DbcCodec
    from vecu.faults import FaultInjector
    from vecu.plant.drive import LongitudinalPart
    from vecu.plant.node import PlantNode
    from vecu.plant.throttle import (
        InputConfig,
        InputGenerator,
        ThrottlePart,
        ThrottlePlant,
        ThrottlePlantConfig,
    )
    from vecu.rng import rng_streams

    buses = []

    def make(channel: str, with_speed: bool = False):
        codec = DbcCodec()
        rngs = rng_streams(0, ("i", "p", "f"))
        plant_bus, tester = open_bus(channel=channel), open_bus(channel=channel)
        buses.extend((plant_bus, tester))
        inj = FaultInjector(rngs["f"])
        parts = [ThrottlePart(codec, ThrottlePlant(ThrottlePlantConfig(), rngs["p"]),
                              InputGenerator(InputConfig(), rngs["i"]), inj)]
        if with_speed:
            parts.append(LongitudinalPart(codec, 3, ("paper",)))
        return codec, PlantNode(plant_bus, codec, inj, parts), tester, inj

    yield make
    for bus in buses:
        bus.shutdown()


@pytest.fixture
def dask_scheduler(tmp_path):
    """A real `dask scheduler` and one `dask worker` process (one thread) on 127.0.0.1, started
    in their own process groups and killed after the test; yields the scheduler's address."""
    import json
    import os
    import shutil
    import signal
    import subprocess
    import sys
    import time

    pytest.importorskip("distributed")
    dask = shutil.which("dask", path=str(Path(sys.executable).parent))
    if dask is None:
        pytest.skip("the dask command is not installed")
    env = {**os.environ, "VECU_KERNELS": os.environ.get("VECU_KERNELS", "python"),
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}

    def spawn(args: list[str]) -> subprocess.Popen:
        return subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True, env=env)

    def kill(proc: subprocess.Popen) -> None:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)

    sched_file = tmp_path / "scheduler.json"
    scheduler = spawn([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                       "--no-dashboard", "--scheduler-file", str(sched_file)])
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert sched_file.exists(), "dask scheduler did not start"
        worker = spawn([dask, "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                        "--nworkers", "1", "--no-dashboard"])
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        yield address
    finally:
        if worker is not None:
            kill(worker)
        kill(scheduler)
        assert scheduler.poll() is not None and (worker is None or worker.poll() is not None)
