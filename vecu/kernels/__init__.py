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
its compiled dispatcher. numba links the kernels a kernel calls into its cache entry but only
watches the kernel's own file; so each cache entry is keyed by the code this process loaded:
a hash of the byte code and module constants of every module the kernel reaches through its
globals (the kernel's, its callees', transitively), kept beside numba's index (`<index>.key`).
A cache written from other code (a callee edited, also by a process that loaded the old source
before the edit) is dropped and compiled again (`_code_key`, `_drop_stale_cache`): one
mechanism for every kernel, no module keeps a guard of its own.
One way to call a kernel: `k(...)`, from Python and from other kernels alike. A small piece
(a few arithmetic operations, shared by bigger kernels: `@kernel(small=True)`) called from
Python runs as Python under every backend (a compiled call from Python costs more than the
piece itself); inside compiled code it is compiled with its caller. `constants(values)` and
`record(dtype)` give a kernel's arguments in the form the active backend takes fast (a float64
array or a structured array compiled; tuples of Python floats or a dict of named Python numbers
as Python); `pack(*parts)` gives several read-only arrays as one argument (`part(p, i)`,
`table(p, i)`, `numbers(p, i, n)` read them back). `@kernel(setup=fn)` runs fn once before the
kernel is first compiled (an external symbol it links, say).

A numpy form (`@kernel(python=numpy_fn)`): the python backend runs numpy_fn instead of the loops
(the numba backend still compiles fn). A kernel may carry a numpy form only when its loops as
plain Python would make the python backend unusable (per-particle loops: the throttle particle
filter's step and resampling, vecu.estimators.throttle.pf); both forms are tested against each
other (same draws and decisions, results equal to rounding). The same option carries a kernel
on arrays that the python backend runs on their Python lists or a view of them (the same
function; numpy's element access would double a small kernel's time in plain Python). The
choice stays here: callers call `k(...)` under either backend.

Same seed, same backend -> bit-identical output. The two backends agree to rounding (a few ulp:
numba's vector reductions and libm calls may round differently from numpy's); for kernels that
only do scalar IEEE arithmetic and libm calls the outputs are bit-identical (tested per kernel).
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import CodeType, ModuleType
from typing import Any

import numpy as np

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

    __slots__ = ("_compiled", "_options", "_setup", "_signature", "plain", "py", "small")

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any],
                 python: Callable[..., Any] | None = None) -> None:
        self.py = fn
        self.plain = fn if python is None else python  # what the python backend runs
        self.small = bool(options.pop("small", False))
        self._setup: Callable[[], None] | None = options.pop("setup", None)
        self._options = options
        self._compiled: Callable[..., Any] | None = None
        self._signature: tuple | Callable[[], tuple] | None = None

    @property
    def compiled(self) -> Callable[..., Any]:
        """The numba dispatcher (compiles lazily per signature; needs numba)."""
        if self._compiled is None:
            numba = _import_numba()
            if not numba:
                raise KernelBackendError("numba is not installed (pip install 'vecu[fast]')")
            if self._setup is not None:
                self._setup()
            try:
                compiled = numba.njit(cache=True, **self._options)(self.py)
            except RuntimeError:  # no cache locator (function defined outside a file)
                compiled = numba.njit(**self._options)(self.py)
            else:
                _drop_stale_cache(compiled, self.py)
            self._compiled = compiled
            if self._signature is not None:
                self._fix()
        return self._compiled

    def discard_compiled(self) -> None:
        """Forget the compiled code, on disk too (the next use compiles it again)."""
        if self._compiled is not None:
            cache = getattr(self._compiled, "_cache", None)
            if cache is not None:
                cache.flush()
        self._compiled = None

    def fix_signature(self, signature: tuple | Callable[[], tuple]) -> None:
        """Declare this kernel's one signature (numba types, or a function returning them, so
        that numba is imported only to compile): numba compiles it (or loads it from its cache)
        when the kernel is first compiled, and no other; an int or numpy-scalar argument then
        converts to it instead of compiling a new specialisation in the middle of a run."""
        self._signature = signature
        if self._compiled is not None:
            self._fix()

    def _fix(self) -> None:
        sig = self._signature
        self._signature = sig = sig() if callable(sig) else sig
        assert self._compiled is not None and sig is not None
        self._compiled.compile(sig)  # type: ignore[attr-defined]  # a numba dispatcher
        self._compiled.disable_compile()  # type: ignore[attr-defined]  # as above

    def fix_types(self, *example: Any) -> None:
        """fix_signature for the types of these example arguments (numba.typeof of each), under
        the numba backend and once (a kernel's signature is declared one time)."""
        if backend() == "numba" and self._signature is None:
            self.fix_signature(tuple(_import_numba().typeof(a) for a in example))

    def impl(self) -> Callable[..., Any]:
        """The function a call from Python runs under the active backend."""
        return self.compiled if backend() == "numba" and not self.small else self.plain

    def __call__(self, *args: Any) -> Any:
        if _active == "python" or self.small:  # first: a kernel calling kernels in Python
            return self.plain(*args)
        return (self._compiled or self.impl())(*args)


def record(dtype: np.dtype, **values: Any) -> Any:
    """A one-element record of dtype's named fields (the others 0), as the active backend's
    kernels read and write it fast, `r[0]["field"]` either way: a numpy structured array when
    they run compiled (numba types its fields), a list of one dict of Python numbers when they
    run as Python (a numpy field access and numpy scalars cost ~10x a dict's and a float's)."""
    arr = np.zeros(1, dtype=dtype)
    for name, value in values.items():
        arr[0][name] = value
    if backend() == "numba":
        return arr
    return [{name: arr[0][name].item() for name in dtype.names}]


def constants(values: Any) -> Any:
    """Read-only kernel arguments (numbers, or equal-length rows of numbers) as the active
    backend takes them fast: a C-contiguous float64 array when kernels run compiled, a tuple
    of Python floats (of such tuples) when they run as Python (numpy scalars make Python
    arithmetic several times slower). Made where the kernels' caller is built."""
    arr = np.ascontiguousarray(values, dtype=np.float64)
    if backend() == "numba":
        return arr
    if arr.ndim == 1:
        return tuple(arr.tolist())
    return tuple(tuple(row) for row in arr.tolist())


_SIMPLE = (bool, int, float, complex, str, bytes, type(None))
_module_keys: dict[str, tuple[ModuleType, bytes]] = {}  # name -> (module, digest of its code)


def _code_bytes(code: CodeType) -> bytes:
    """A code object's byte code, names and constants, nested code included (marshal's output
    depends on reference counts: not stable across processes)."""
    parts = [code.co_code, repr((code.co_names, code.co_varnames, code.co_freevars,
                                 code.co_cellvars, code.co_argcount)).encode()]
    for const in code.co_consts:
        if isinstance(const, CodeType):
            parts.append(_code_bytes(const))
        elif isinstance(const, frozenset):  # `x in {...}`: its repr's order follows str hashing
            parts.append(repr(sorted(repr(e) for e in const)).encode())
        else:
            parts.append(repr(const).encode())
    return b"\x00".join(parts)


def _module_key(module: ModuleType) -> bytes:
    """Digest of a module's functions' byte code (nested ones included) and its constants by
    the UPPER_CASE convention (numbers, strings, tuples of them, arrays: numba freezes the
    globals it reads), as loaded in this process. Lower-case globals are module state (flags
    that change in a run), not hashed."""
    hit = _module_keys.get(module.__name__)
    if hit is not None and hit[0] is module:  # not a module imported again under its name
        return hit[1]
    h = hashlib.sha256(module.__name__.encode())
    for name, v in sorted(vars(module).items()):
        fn = v.py if isinstance(v, Kernel) else getattr(v, "py_func", v)
        code = getattr(fn, "__code__", None)
        if code is not None and getattr(fn, "__module__", None) == module.__name__:
            h.update(name.encode() + _code_bytes(code))
        elif not name.isupper():
            continue
        elif isinstance(v, _SIMPLE) or (isinstance(v, tuple)
                                        and all(isinstance(e, _SIMPLE) for e in v)):
            h.update(name.encode() + repr(v).encode())
        elif type(v).__name__ == "ndarray":
            h.update(name.encode() + str((v.dtype, v.shape)).encode() + v.tobytes())
        elif type(v).__module__ == "numpy.dtypes":  # a record layout kernels view arrays as
            h.update(name.encode() + repr(v.descr).encode())
    key = h.digest()
    _module_keys[module.__name__] = (module, key)
    return key


def _reached_modules(fn: Callable[..., Any]) -> set[str]:
    """The modules of fn and of every function of its package (vecu) it reaches by a global
    name (directly, or as an attribute of an imported module), transitively: Kernel objects,
    plain helpers, numba dispatchers. Third-party code is numba's to watch (its index holds
    numba's version)."""
    package = fn.__module__.split(".")[0] + "."
    modules: set[str] = set()
    seen: set[int] = set()
    todo = [fn]
    while todo:
        f = todo.pop()
        code = getattr(f, "__code__", None)
        if code is None or id(f) in seen or not f"{f.__module__}.".startswith(package):
            continue
        seen.add(id(f))
        modules.add(f.__module__)
        names = set(code.co_names)
        stack = list(code.co_consts)
        while stack:  # nested functions and lambdas
            const = stack.pop()
            if hasattr(const, "co_names"):
                names.update(const.co_names)
                stack.extend(const.co_consts)
        glb = getattr(f, "__globals__", {})
        values: list[Any] = [glb.get(name) for name in names]
        for mod in [v for v in values if isinstance(v, ModuleType)]:  # mi._integrate_event
            values += [getattr(mod, name, None) for name in names]
        for v in values:
            if isinstance(v, Kernel):
                todo.append(v.py)
            elif hasattr(v, "py_func"):  # a numba dispatcher
                todo.append(v.py_func)
            elif callable(v) and hasattr(v, "__code__"):
                todo.append(v)
    return modules


def _code_key(fn: Callable[..., Any]) -> str:
    """Hex digest of the code fn's compiled version is made of (see the module)."""
    h = hashlib.sha256()
    for name in sorted(_reached_modules(fn)):
        module = sys.modules.get(name)
        h.update(_module_key(module) if module is not None else name.encode())
    return h.hexdigest()


def _drop_stale_cache(compiled: Any, fn: Callable[..., Any]) -> None:
    """Flush compiled's disk cache when it was written from other code than this process's (its
    key file differs), and key it by this process's code."""
    cache = getattr(compiled, "_cache", None)
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    if index is None:
        return
    key_path = Path(f"{index}.key")
    key = _code_key(fn)
    try:
        if key_path.read_text() == key:
            return
    except OSError:  # no key yet (a cold cache, or written before keys existed)
        pass
    cache.flush()
    try:  # atomically: a process reading it sees the old key or the new one
        tmp = key_path.with_name(f"{key_path.name}.{os.getpid()}")
        tmp.write_text(key)
        os.replace(tmp, key_path)
    except OSError:  # a read-only cache: numba will not write entries there either
        pass


def kernel(fn: Callable[..., Any] | None = None, *, python: Callable[..., Any] | None = None,
           **options: Any) -> Any:
    """Decorator: `@kernel`, `@kernel(small=True)`, `@kernel(setup=fn)`, `@kernel(python=fn)`
    (module docstring) or `@kernel(error_model="numpy")`; numba options pass through (never
    fastmath: it would break the agreement with the Python path)."""
    if "fastmath" in options:
        raise ValueError("fastmath is not allowed in vecu kernels")
    if fn is None:
        return lambda f: Kernel(f, dict(options), python)
    return Kernel(fn, options, python)


def pack(*parts: Any) -> Any:
    """Several read-only kernel arguments (float arrays of one or two dimensions, tuples of
    numbers) as one, each read back with `part(p, i)` / `table(p, i)` (part i of one / two
    dimensions) in either backend. Compiled: one float64 array, a header (the number of parts,
    their offsets, each part's rows and columns) then the parts flat, C order (numba types one
    argument where it would type one per part, ~0.25 us each on every call from Python; a
    tuple of floats costs more); as Python: the tuple of the parts as given (Python reads a
    tuple of floats faster than an array). Made where the kernels' caller is built."""
    if backend() != "numba":
        return parts
    flat = [np.ascontiguousarray(p, dtype=np.float64) for p in parts]
    n = len(flat)
    offsets = np.cumsum([1 + (n + 1) + 2 * n] + [a.size for a in flat])
    shapes = [d for a in flat for d in (a.shape[0], a.shape[1] if a.ndim == 2 else 0)]
    return np.concatenate([np.array([n, *offsets, *shapes], dtype=np.float64),
                           *(a.ravel() for a in flat)])


def _part_as_given(p: Any, i: int) -> Any:
    return p[i]


@kernel(python=_part_as_given)
def part(p: Any, i: int) -> Any:
    """Part i (one dimension) of a pack(): a view of the packed array compiled, the part as
    given as Python."""
    return p[int(p[1 + i]):int(p[2 + i])]


@kernel(python=_part_as_given)
def table(p: Any, i: int) -> Any:
    """Part i (two dimensions) of a pack(): a C-ordered view of the packed array compiled,
    the part as given as Python."""
    n = int(p[0])
    return p[int(p[1 + i]):int(p[2 + i])].reshape((int(p[n + 2 + 2 * i]),
                                                     int(p[n + 3 + 2 * i])))


def _link_fixed_tuple() -> None:
    global _to_fixed_tuple
    from numba.np.unsafe.ndarray import to_fixed_tuple

    _to_fixed_tuple = to_fixed_tuple


_to_fixed_tuple: Any = None  # numba's, linked before `numbers` is first compiled


def _numbers_as_given(p: Any, i: int, n: int) -> Any:
    return p[i]


@kernel(python=_numbers_as_given, setup=_link_fixed_tuple)
def numbers(p: Any, i: int, n: int) -> Any:
    """Part i of a pack() given as a tuple of n numbers (for a kernel that takes a tuple):
    compiled, that part of the packed array as a tuple of n floats; as Python, the part as
    given."""
    return _to_fixed_tuple(p[int(p[1 + i]):int(p[2 + i])], n)
