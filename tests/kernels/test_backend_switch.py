"""vecu.kernels: backend selection (VECU_KERNELS), the python fallback, the CLI's one-line error."""

from __future__ import annotations

import numpy as np
import pytest

from vecu import kernels
from vecu.cli import main


@pytest.fixture
def fresh_backend(monkeypatch):
    """Unresolved backend state, restored afterwards."""
    monkeypatch.setattr(kernels, "_active", None)
    yield
    monkeypatch.setattr(kernels, "_active", None)


@kernels.kernel
def _weighted_sum(n: int, w: float) -> float:
    s = 0.0
    for i in range(n):
        s += w * i
    return s


@kernels.kernel
def _twice_weighted_sum(n: int, w: float) -> float:
    """A kernel calling another kernel (as the estimators' kernels call the shared ones)."""
    return _weighted_sum(n, w) + _weighted_sum(n, 2.0 * w)


def test_vecu_kernels_selects_the_backend_and_it_agrees_with_python(backend, fresh_backend,
                                                                    monkeypatch):
    monkeypatch.setenv(kernels.ENV_VAR, backend)
    assert kernels.backend() == backend
    fn = _weighted_sum.impl()
    assert (fn is _weighted_sum.py) == (backend == "python")
    assert backend == "python" or hasattr(fn, "signatures")  # a numba dispatcher
    assert _weighted_sum(4, 0.5) == 3.0
    assert _weighted_sum(1000, 0.25) == _weighted_sum.py(1000, 0.25)
    assert _twice_weighted_sum(1000, 0.25) == _twice_weighted_sum.py(1000, 0.25) == 374625.0


def test_auto_without_numba_falls_back_to_python(fresh_backend, monkeypatch):
    monkeypatch.setattr(kernels, "_numba", False)
    monkeypatch.setenv(kernels.ENV_VAR, "auto")
    assert kernels.backend() == "python"
    assert not kernels.numba_available()
    with pytest.raises(kernels.KernelBackendError, match="not installed"):
        kernels.set_backend("numba")


def test_unknown_backend_is_a_one_line_cli_error(fresh_backend, monkeypatch, capsys):
    monkeypatch.setenv(kernels.ENV_VAR, "cuda")
    assert main(["run", "--duration", "0.01"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "VECU_KERNELS='cuda'" in err


def test_fastmath_is_refused():
    with pytest.raises(ValueError, match="fastmath"):
        kernels.kernel(fastmath=True)


def _loops(x):
    return x + 1.0


def _vectorised(x):
    return x + 2.0  # differs on purpose: shows which form ran


def test_a_numpy_form_runs_under_python_and_the_loops_compile_under_numba():
    k = kernels.kernel(_loops, python=_vectorised)
    with kernels.using("python"):
        assert k(1.0) == 3.0 and k.impl() is _vectorised
    if kernels.numba_available():
        with kernels.using("numba"):
            assert k(1.0) == 2.0 and k(1.0) == 2.0  # compiled on first call, then cached
    assert kernels.kernel(python=_vectorised)(_loops).plain is _vectorised
    assert kernels.kernel(_loops).plain is _loops


def test_set_backend_returns_the_previous_one(fresh_backend, monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setenv(kernels.ENV_VAR, "numba")
    assert kernels.set_backend("python") == "numba"
    assert _weighted_sum.impl() is _weighted_sum.py


def test_discard_compiled_recompiles(fresh_backend, monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setenv(kernels.ENV_VAR, "numba")
    first = _weighted_sum.compiled
    assert _weighted_sum(10, 1.0) == 45.0
    _weighted_sum.discard_compiled()
    assert _weighted_sum.compiled is not first
    assert _weighted_sum(10, 1.0) == 45.0


def numba_types():
    from numba import types

    return types


def test_cold_cache_is_announced_once_per_install(fresh_backend, monkeypatch, tmp_path):
    """A fresh checkout (no numba cache file next to the sources) gets a one-line notice."""
    pytest.importorskip("numba")
    monkeypatch.setenv(kernels.ENV_VAR, "numba")
    assert kernels.cache_is_cold() is False  # this session's kernels are cached already
    import pathlib

    real_glob = pathlib.Path.glob
    monkeypatch.setattr(pathlib.Path, "glob",
                        lambda self, pat: iter(()) if pat.endswith(".nbi") else real_glob(self, pat))
    assert kernels.cache_is_cold() is True
    monkeypatch.setenv(kernels.ENV_VAR, "python")
    monkeypatch.setattr(kernels, "_active", None)
    assert kernels.cache_is_cold() is False


def test_using_restores_the_previous_backend_even_after_a_switch_inside(fresh_backend,
                                                                         monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setenv(kernels.ENV_VAR, "python")
    with kernels.using("numba") as active:
        assert active == kernels.backend() == "numba"
        kernels.set_backend("auto")  # numba as well: the block's own switch
    assert kernels.backend() == "python"
    with pytest.raises(RuntimeError), kernels.using("python"):
        raise RuntimeError("inside")
    assert kernels.backend() == "python"


_CALLEE = """import math
from vecu.kernels import kernel


@kernel
def inner(x):
    return x + {value}
"""
_CALLER = """from vecu.kernels import kernel
from {pkg}.callee import inner


@kernel
def outer(x):
    return 2.0 * inner(x)
"""


def test_a_changed_callee_drops_its_callers_disk_cache(tmp_path, monkeypatch):
    """numba's cache only watches a kernel's own file; vecu.kernels keys each entry by the code
    it reaches (vecu.kernels._code_key), so a kernel calling into another file is recompiled
    when that file's code changed, even when the file looks older than the cache (a process
    that loaded the old source wrote the cache after the edit), and loaded when nothing did."""
    pytest.importorskip("numba")
    import importlib
    import os
    import sys

    pkg = f"vecu_cache_probe_{os.getpid()}"
    root = tmp_path / pkg
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "caller.py").write_text(_CALLER.format(pkg=pkg))
    monkeypatch.syspath_prepend(str(tmp_path))

    def caller_outer():
        return sys.modules[f"{pkg}.caller"].outer.compiled

    def outer_of(value: float, stamp: float) -> float:
        callee = root / "callee.py"
        callee.write_text(_CALLEE.format(value=value))
        os.utime(callee, (stamp, stamp))
        for name in [m for m in sys.modules if m.startswith(pkg)]:
            del sys.modules[name]
        importlib.invalidate_caches()
        caller = importlib.import_module(f"{pkg}.caller")
        with kernels.using("numba"):
            return caller.outer(1.0)

    now = (root / "caller.py").stat().st_mtime
    assert outer_of(1.0, now - 100.0) == 4.0  # compiled and cached
    assert list(root.glob("__pycache__/caller.outer-*.nbi.key"))
    assert outer_of(1.0, now - 100.0) == 4.0
    assert caller_outer().stats.cache_hits  # loaded from the cache: same code, same key
    assert outer_of(5.0, now - 100.0) == 12.0  # callee changed, its file older: not the stale 4.0
    assert not caller_outer().stats.cache_hits  # compiled again
    assert outer_of(5.0, now - 100.0) == 12.0 and caller_outer().stats.cache_hits


COLD_THEN_WARM = """
from vecu import kernels
from vecu.models.lateral import tyre_force
cold = kernels.cache_is_cold()
tyre_force.compiled(1.0, 1.3, 10.0, 0.01)  # compiled and written to numba's cache
print(cold, kernels.cache_is_cold())
"""


def test_cold_cache_is_seen_wherever_numba_keeps_it(tmp_path):
    """numba caches where its locators say: NUMBA_CACHE_DIR when set (also the user-wide
    directory of a package installed read-only). A fresh cache there is cold although the
    checkout's own __pycache__ holds kernels, and one compiled kernel warms it (issue 16)."""
    pytest.importorskip("numba")
    import os
    import subprocess
    import sys

    env = {**os.environ, "VECU_KERNELS": "numba", "NUMBA_CACHE_DIR": str(tmp_path / "nc")}
    res = subprocess.run([sys.executable, "-c", COLD_THEN_WARM], capture_output=True, text=True,
                         env=env, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["True", "False"]
    assert list((tmp_path / "nc").rglob("*.nbi"))


_setups: list[str] = []


@kernels.kernel(small=True)
def _small_square_sum(a: float, b: float) -> float:
    return a * a + b * b


@kernels.kernel(setup=lambda: _setups.append("linked"))
def _hypot_sq(a: float, b: float) -> float:
    """A kernel calling a small one (compiled with it under numba)."""
    return _small_square_sum(a, b)


def test_small_kernels_run_as_python_from_python_and_compiled_inside_kernels(backend):
    """k(...) is the one call: a small kernel called from Python runs its Python function under
    every backend; inside a compiled kernel it is compiled; setup runs once before the first
    compilation (never under python)."""
    before = list(_setups)
    assert _small_square_sum.impl() is _small_square_sum.py
    assert _small_square_sum(3.0, 4.0) == 25.0
    assert _hypot_sq(3.0, 4.0) == 25.0 == _hypot_sq.py(3.0, 4.0)
    assert (_hypot_sq.impl() is _hypot_sq.py) == (backend == "python")
    assert _hypot_sq(1.0, 2.0) == 5.0
    assert _setups == (["linked"] if backend == "numba" else before)


def test_constants_and_records_in_the_backends_fast_form(backend):
    """constants: a float64 array for numba, tuples of Python floats as Python; record: r[0]
    ["field"] readable and writable either way, its other fields 0."""
    cst = kernels.constants([[1, 2.5], [3, 4]])
    rec = kernels.record(np.dtype([("x", "f8"), ("n", "i8"), ("on", "?")]), x=1.5)
    if backend == "numba":
        assert isinstance(cst, np.ndarray) and cst.dtype == np.float64 and cst.flags.c_contiguous
        assert isinstance(rec, np.ndarray) and rec.shape == (1,)
    else:
        assert cst == ((1.0, 2.5), (3.0, 4.0)) and type(cst[0][0]) is float
        assert type(rec[0]["x"]) is float and type(rec[0]["n"]) is int
    assert (rec[0]["x"], rec[0]["n"], rec[0]["on"]) == (1.5, 0, False)
    rec[0]["n"] += 2
    assert rec[0]["n"] == 2
