"""Optional compiled kernels: numba when it is installed (`pip install vecu[fast]`), plain Python
and numpy otherwise.

A kernel is written once as a numba-compatible Python function and wrapped with `kernel(fn)`.
Calling the wrapper runs the numba-compiled version when the active backend is "numba" and the
Python function itself otherwise. The backend is chosen by the environment variable
``VECU_KERNELS``:

  auto    (default) numba if it can be imported, else python
  numba   numba; a one-line error if it is not installed
  python  never compile (the reference: the golden traces and bit-identity tests use it)

`set_backend` switches it at run time (tests compare the two). Compiled code is cached on disk
(numba's ``cache=True``: next to the sources, or the user cache directory when that is read-only),
so only the first process on a machine pays the compile time (~1-3 s per kernel).

A kernel may call other kernels (small shared pieces such as vecu.estimators.common.small_linalg
or vecu.models.lateral.tyre_force): under numba a Kernel object used inside compiled code is
its compiled dispatcher, and a kernel's disk cache is dropped when a file it calls into (other
kernels, helpers) is newer than that cache (numba itself only watches the kernel's own file).
Plain-Python hot paths call `k.py` directly: a compiled call from Python costs more than a tiny
kernel.

Same seed, same backend -> bit-identical output. The two backends agree to rounding (a few ulp:
numba's vector reductions and libm calls may round differently from numpy's); for kernels that
only do scalar IEEE arithmetic and libm calls the outputs are bit-identical (tested per kernel).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from vecu.errors import ConfigError

BACKENDS = ("auto", "numba", "python")
ENV_VAR = "VECU_KERNELS"

_numba: Any = None  # the numba module once imported, False if it cannot be
_active: str | None = None  # "numba" or "python" once resolved


class KernelBackendError(ConfigError):
    """VECU_KERNELS asks for a backend that is not available (or is not a backend at all)."""


def _import_numba() -> Any:
    global _numba
    if _numba is None:
        try:
            import numba
        except Exception:  # noqa: BLE001 (ImportError or a broken llvmlite: fall back)
            _numba = False
        else:
            _numba = numba
            _register_kernel_type(numba)
    return _numba


def _register_kernel_type(numba: Any) -> None:
    """Let compiled code call a Kernel object: numba types it as the kernel's dispatcher."""
    from numba.core import types
    from numba.extending import typeof_impl

    @typeof_impl.register(Kernel)
    def _typeof_kernel(val: Kernel, c: Any) -> Any:
        return types.Dispatcher(val.compiled)


def numba_available() -> bool:
    """True if numba can be imported here."""
    return bool(_import_numba())


def _resolve(name: str) -> str:
    if name not in BACKENDS:
        raise KernelBackendError(
            f"{ENV_VAR}={name!r}: expected one of {', '.join(BACKENDS)}")
    if name == "auto":
        return "numba" if numba_available() else "python"
    if name == "numba" and not numba_available():
        raise KernelBackendError(
            f"{ENV_VAR}=numba but numba is not installed (pip install 'vecu[fast]')")
    return name


def backend() -> str:
    """The active backend, "numba" or "python" (resolved from VECU_KERNELS on first use)."""
    global _active
    if _active is None:
        _active = _resolve(os.environ.get(ENV_VAR, "auto").strip().lower() or "auto")
    return _active


def set_backend(name: str) -> str:
    """Switch the backend ("auto", "numba", "python"); returns the previous one."""
    previous = backend()
    global _active
    _active = _resolve(name)
    return previous


@contextmanager
def using(name: str) -> Iterator[str]:
    """Run a block under backend `name` ("auto", "numba", "python"); the backend that was active
    comes back afterwards, also after a set_backend inside the block."""
    previous = set_backend(name)
    try:
        yield backend()
    finally:
        set_backend(previous)


def cache_is_cold() -> bool:
    """True under the numba backend when numba's disk cache holds no compiled kernel of vecu
    yet (a fresh checkout or install: the first run compiles, ~40 s); False under python."""
    if backend() != "numba":
        return False
    return not any(any(d.glob("*.nbi")) for d in kernel_cache_dirs() if d.is_dir())


def kernel_cache_dirs() -> list[Path]:
    """Where numba caches the kernels of each vecu source directory, as numba chooses it
    (numba.core.caching's locators, in order): NUMBA_CACHE_DIR when set; else __pycache__
    beside the sources when that is writable (a checkout, an editable install); else the
    user-wide cache directory (a package installed where the user cannot write)."""
    import hashlib

    from numba.core import config as numba_config
    from numba.misc.appdirs import AppDirs

    root = Path(__file__).resolve().parents[1]
    user_wide = Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)
    dirs = []
    for src in sorted({p.parent for p in root.rglob("*.py")}):
        subpath = f"{src.name}_{hashlib.sha1(str(src).encode()).hexdigest()}"
        if numba_config.CACHE_DIR:
            dirs.append(Path(numba_config.CACHE_DIR) / subpath)
        elif os.access(src, os.W_OK) and (not (src / "__pycache__").exists()
                                          or os.access(src / "__pycache__", os.W_OK)):
            dirs.append(src / "__pycache__")
        else:
            dirs.append(user_wide / subpath)
    return dirs


class Kernel:
    """A numba-compatible function, compiled on first use under the numba backend."""

    __slots__ = ("_compiled", "_options", "py")

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any]) -> None:
        self.py = fn
        self._options = options
        self._compiled: Callable[..., Any] | None = None

    @property
    def compiled(self) -> Callable[..., Any]:
        """The numba dispatcher (compiles lazily per signature; needs numba)."""
        if self._compiled is None:
            numba = _import_numba()
            if not numba:
                raise KernelBackendError("numba is not installed (pip install 'vecu[fast]')")
            try:
                compiled = numba.njit(cache=True, **self._options)(self.py)
            except RuntimeError:  # no cache locator (function defined outside a file)
                compiled = numba.njit(**self._options)(self.py)
            else:
                _drop_stale_cache(compiled, self.py)
            self._compiled = compiled
        return self._compiled

    def discard_compiled(self) -> None:
        """Forget the compiled code, on disk too (numba's cache does not see changes to other
        kernels a kernel calls: a caller that detects such staleness recompiles with this)."""
        if self._compiled is not None:
            cache = getattr(self._compiled, "_cache", None)
            if cache is not None:
                cache.flush()
        self._compiled = None

    def fix_signature(self, signature: tuple) -> None:
        """Compile (or load from numba's cache) this one signature now and switch further
        compilation off: an int or numpy-scalar argument then converts to it instead of
        compiling a new specialisation in the middle of a run."""
        disp = self.compiled
        disp.compile(signature)
        disp.disable_compile()

    def impl(self) -> Callable[..., Any]:
        """The function for the active backend (hot callers fetch it once per call site)."""
        return self.compiled if backend() == "numba" else self.py

    def __call__(self, *args: Any) -> Any:
        if _active == "python":  # the common case first: a kernel calling kernels in Python
            return self.py(*args)
        return self.impl()(*args)


def rebuild_if_stale(kernels: Sequence[Kernel], current: Callable[[], bool],
                     compile_again: Callable[[], None], what: str) -> None:
    """numba links the kernels a kernel calls into its cache entry and does not see them
    change; vecu's file-time check (_drop_stale_cache) misses an entry written by a process that
    had loaded the old source before the file changed. `current()` compares a sample call of
    the cached kernels with their parts called one by one; when it fails, the kernels are
    dropped (their disk cache too), `compile_again()` builds them from the sources, and
    current() must then hold (RuntimeError otherwise: a real disagreement, a bug)."""
    if current():
        return
    for k in kernels:
        k.discard_compiled()
    compile_again()
    if not current():
        raise RuntimeError(f"compiled {what} disagree with the kernels they call")


def _called_files(fn: Callable[..., Any]) -> set[str]:
    """Source files of fn and of every function it calls by a global name, transitively (Kernel
    objects, plain helpers, numba dispatchers)."""
    files: set[str] = set()
    seen: set[int] = set()
    todo = [fn]
    while todo:
        f = todo.pop()
        code = getattr(f, "__code__", None)
        if code is None or id(f) in seen:
            continue
        seen.add(id(f))
        files.add(code.co_filename)
        names = set(code.co_names)
        for const in code.co_consts:  # nested functions and lambdas
            if hasattr(const, "co_names"):
                names.update(const.co_names)
        glb = getattr(f, "__globals__", {})
        for name in names:
            v = glb.get(name)
            if isinstance(v, Kernel):
                todo.append(v.py)
            elif hasattr(v, "py_func"):  # a numba dispatcher
                todo.append(v.py_func)
            elif callable(v) and hasattr(v, "__code__"):
                todo.append(v)
    return files


def _drop_stale_cache(compiled: Any, fn: Callable[..., Any]) -> None:
    """Flush compiled's disk cache when a file fn calls into changed after it was written."""
    cache = getattr(compiled, "_cache", None)
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    if index is None or not os.path.exists(index):
        return
    written = os.path.getmtime(index)
    if any(os.path.exists(f) and os.path.getmtime(f) > written for f in _called_files(fn)):
        cache.flush()


def kernel(fn: Callable[..., Any] | None = None, **options: Any) -> Any:
    """Decorator: `@kernel` or `@kernel(error_model="numpy")`; numba options pass through
    (never fastmath: it would break the agreement with the Python path)."""
    if "fastmath" in options:
        raise ValueError("fastmath is not allowed in vecu kernels")
    if fn is None:
        return lambda f: Kernel(f, options)
    return Kernel(fn, options)
