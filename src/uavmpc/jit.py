"""The one way uavmpc compiles a kernel: ``@kernel`` (numba ``njit``, cached on disk).

numba's on-disk cache checks only the source file of the function it caches: a kernel that
calls a kernel from another file would keep running stale machine code after that other file
changed. uavmpc's kernels call each other across its stages (the world's batched tick calls the
tracker, the SE(3) law and the plant), so every kernel of the package is cached in a folder
named after a hash of the sources compiled code can depend on (the modules that hold kernels
and, transitively, the package modules they import): any edit there starts a fresh cache, an
edit to a driver or an application outside them does not, and an unchanged install shares one
cache between processes (campaign workers, nodes).

The folder is ``$UAVMPC_CACHE_DIR`` or ``~/.cache/uavmpc/numba``, one sub-folder per hash; older
sub-folders are left for the user to delete. Only uavmpc's kernels use it: numba's global cache
setting is restored right after each decoration.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import platform
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar, cast, overload

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.core import event as numba_event
from numba.extending import intrinsic

F = TypeVar("F", bound=Callable[..., Any])
R = TypeVar("R")

#: Let LLVM reorder sums (vectorised dot products) and fuse multiply-adds, but keep NaN/inf
#: semantics: the kernels rely on isnan/isfinite to reject bad data.
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}
#: :data:`FASTMATH` without reordering sums: for a kernel whose sums must come out bit for bit
#: as another kernel's that LLVM does not reorder.
FASTMATH_ORDERED = {"contract", "nsz", "arcp"}


_IMPORT = re.compile(r"^\s*(?:from|import)\s+(uavmpc(?:\.\w+)*)", re.MULTILINE)


def _compiled_sources(root: Path) -> list[Path]:
    """The modules compiled code can depend on: those that hold kernels (``@kernel``), this
    one, and, transitively, every package module they import (constants and helpers a kernel
    reads are frozen into its machine code). A driver or an application outside that closure
    (one that only calls kernels, binds them or sets their threads) can change without a
    recompilation."""
    files = {p: p.read_text(encoding="utf-8") for p in root.rglob("*.py")}

    def resolve(name: str) -> list[Path]:
        parts = name.split(".")[1:]
        for n in range(len(parts), -1, -1):
            base = root.joinpath(*parts[:n])
            for cand in (base.with_suffix(".py"), base / "__init__.py"):
                if cand in files:
                    return [cand]
        return []

    holds_kernels = re.compile(r"^@kernel\b", re.MULTILINE)
    todo = [p for p, text in files.items()
            if holds_kernels.search(text) or p == root / "jit.py"]
    seen = set(todo)
    while todo:
        path = todo.pop()
        for name in _IMPORT.findall(files[path]):
            for dep in resolve(name):
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
    return sorted(seen)


def _sources_hash() -> str:
    root = Path(__file__).resolve().parent
    digest = hashlib.sha1(usedforsecurity=False)
    for path in _compiled_sources(root):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> str:
    base = os.environ.get("UAVMPC_CACHE_DIR") or str(Path.home() / ".cache" / "uavmpc" / "numba")
    return str(Path(base) / _sources_hash())


CACHE_DIR = _cache_dir()


@overload
def kernel(fn: F, /) -> F: ...


@overload
def kernel(fn: None = None, /, *, allocates: bool = False,
           **options: object) -> Callable[[F], F]: ...


def kernel(fn: F | None = None, /, *, allocates: bool = False,
           **options: Any) -> F | Callable[[F], F]:
    """``numba.njit(cache=True, **options)`` with the cache in :data:`CACHE_DIR`, compiled
    without numba's reference counting unless ``allocates``.

    Use as ``@kernel``, ``@kernel(fastmath=FASTMATH)`` or ``@kernel(allocates=True)``.

    numba counts the references to every array a compiled function holds, with an atomic
    add and subtract, and keeps those it cannot prove redundant: around a call of a kernel
    that has branches or loops, once per array it is passed (a record of 29 arrays costs 58)
    and per view it takes (``rows.x[i]``). A kernel that only borrows the arrays its caller
    holds needs none of that, so a kernel is compiled without numba's runtime (its ``_nrt``
    flag off), and the atomics vanish. A kernel that creates an array (``np.empty``, a copy,
    an array expression, a slice assignment numba may copy through, a ``parallel=True`` loop)
    or receives a new one from a kernel it calls must say ``allocates=True``: it is compiled
    with the runtime, which frees those arrays. Forgetting it is caught: making an array
    without the runtime does not compile (numba says "NRT required but not enabled", or that
    only arrays passed in can be returned: its constructors are kernels too), and a new array
    received from a call would never be freed, which ``tests/test_jit.py`` looks for over
    whole flights (the runtime's allocation counts). The machine code's arithmetic is the
    same either way: the flights are bit for bit those with the runtime everywhere
    (``benchmarks/final_states.py``). Measured in docs/scale.md ("Reference counts").
    """
    # Set on every kernel: a callee without the flag would inherit its caller's.
    options = {**options, "_nrt": bool(allocates or options.get("parallel"))}

    def decorate(f: F) -> F:
        # numba.config sets its options through globals() at import: mypy cannot see them
        saved = numba.config.CACHE_DIR  # type: ignore[attr-defined]
        numba.config.CACHE_DIR = CACHE_DIR  # type: ignore[attr-defined]
        try:
            compiled: F = numba.njit(cache=True, **options)(f)  # numba is untyped
            return compiled
        finally:
            numba.config.CACHE_DIR = saved  # type: ignore[attr-defined]

    return decorate(fn) if fn is not None else decorate


def intrinsic_returning(result: type[R]) -> Callable[[Callable[..., Any]], Callable[..., R]]:
    """numba's ``@intrinsic``, typed as compiled code calls it: ``f(*args) -> result``.

    numba's stubs type an intrinsic's call with its typing function's parameters
    (``typingctx`` first) and a ``Never`` result: the call from Python, which raises. A kernel
    calls it without ``typingctx`` and gets a value of the type its signature builds."""

    def decorate(fn: Callable[..., Any]) -> Callable[..., R]:
        return cast("Callable[..., R]", intrinsic(fn))

    return decorate


def available_threads() -> int:
    """The threads a parallel kernel can use in this process: every core, unless
    ``NUMBA_NUM_THREADS`` set fewer before numba started."""
    # set through numba.config's globals() at import: mypy cannot see it
    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]


#: The environment variable that sets the default thread count of the parallel kernels
#: (:func:`default_threads`), like ``OMP_NUM_THREADS`` for OpenMP programs.
THREADS_ENV = "UAVMPC_THREADS"


def default_threads() -> int:
    """The threads a parallel kernel uses unless told otherwise: ``$UAVMPC_THREADS`` if it is
    an integer from 1 to :func:`available_threads` (any other value is named on stderr and
    ignored), else every core."""
    top = available_threads()
    raw = os.environ.get(THREADS_ENV, "").strip()
    if not raw:
        return top
    if raw.isdigit() and 1 <= int(raw) <= top:
        return int(raw)
    sys.stderr.write(f"uavmpc: {THREADS_ENV}={raw!r} is not an integer from 1 to {top}; "
                     f"using {top} threads\n")
    return top


def runnable_others() -> int:
    """How many other tasks are runnable on this machine right now (Linux's
    ``/proc/loadavg``, less this one), or 0 where it cannot be read."""
    try:
        with open("/proc/loadavg") as f:
            running = int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return 0
    return max(0, running - 1)


def idle_threads() -> int:
    """The threads a world's tick should take by default on this machine now: the cores left
    idle (:func:`default_threads` less the busier of the 1-minute load average, rounded down,
    and the tasks runnable right now besides this one: a load that just began has not yet
    reached the average), at least 1; ``$UAVMPC_THREADS`` when set. A parallel tick waits at
    every tick for its slowest thread, and a thread the OS has parked for other work makes
    it wait for a whole time slice: on this 2-core machine with a load of 3, ``uavmpc run
    swap_through_static`` flew 0.41× real time on 2 threads and 16× on 1 (docs/scale.md)."""
    top = default_threads()
    if os.environ.get(THREADS_ENV, "").strip():
        return top
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average here (Windows): every core
        return top
    busy = max(math.floor(load), runnable_others())
    return max(1, min(top, top - busy))


def set_threads(n: int | None) -> int:
    """Run the parallel kernels (``@kernel(parallel=True)``) of this thread of Python on
    ``n`` threads (None: :func:`default_threads`); returns the count set. Their results
    do not depend on it: each parallel loop gives every row its own outputs and work arrays."""
    top = available_threads()
    if n is None:
        n = default_threads()
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= top:
        raise ValueError(f"threads must be an integer from 1 to {top} (this machine's cores, "
                         f"or NUMBA_NUM_THREADS), got {n!r}")
    numba.set_num_threads(n)
    _threads.n = n
    return n


#: This thread of Python's count of threads (numba keeps one per thread of Python too).
_threads = threading.local()


def thread_count() -> int:
    """The threads this thread of Python runs the parallel kernels on (:func:`set_threads`):
    how many row blocks a driver hands them. numba's own count, read once per thread of
    Python (asking numba costs µs at every tick); set it with :func:`set_threads` or
    :func:`using_threads`, not with ``numba.set_num_threads``."""
    n = getattr(_threads, "n", None)
    if n is None:
        n = _threads.n = numba.get_num_threads()
    return int(n)


if os.environ.get(THREADS_ENV):
    set_threads(None)


@contextlib.contextmanager
def using_threads(n: int | None) -> Iterator[int]:
    """:func:`set_threads` for the ``with`` block only: the count before comes back after
    (a campaign's trials must not change what the rest of the process runs on)."""
    before = numba.get_num_threads()
    try:
        yield set_threads(n)
    finally:
        numba.set_num_threads(before)
        _threads.n = before


def bind(dispatcher: Any, *args: Any) -> Callable[..., Any]:
    """``dispatcher`` compiled for the types of ``args``, callable without numba's per-call
    type inference.

    numba infers the type of every argument on every call; for a record (a NamedTuple of
    arrays) that takes several µs, more than a whole tracker tick's arithmetic. A driver
    that calls a kernel at 100 Hz with the same records binds it once and calls the result.
    The caller must pass arguments of exactly the bound types (records it built itself) and
    bind again when one is replaced by another of a different type.
    """
    signature = tuple(numba.typeof(a) for a in args)
    compiled: Callable[..., Any] = dispatcher.compile(signature)
    return compiled


def _type_key(a: Any) -> Any:
    """What decides how numba types ``a``, cheaply: a record (a tuple) by identity (its
    arrays are fixed), an array by dtype, dimensions, layout (as numba reads it: C before
    F, so that an empty array, both at once, keys as the full ones it is cut from),
    alignment and writability, any other value by its Python type."""
    if type(a) is np.ndarray:
        f = a.flags
        layout = "C" if f.c_contiguous else "F" if f.f_contiguous else "A"
        return (a.dtype.num, a.ndim, layout, f.aligned, f.writeable)
    if isinstance(a, tuple):
        return id(a)
    return type(a)


class Bound:
    """A kernel called through :func:`bind`, bound again whenever the types of its
    arguments change (a record replaced by a grown one, say).

    A driver that calls a kernel with records at every tick pays numba's type inference of
    each record on every call (several µs each, more with cold caches after a world's tick:
    about 20 µs per call of the broadcast writer, docs/scale.md); through this it pays a
    Python check of the arguments instead. The records passed must be the driver's own,
    never modified in place (a NamedTuple's arrays are fixed; their flags must not change).

    Attributes:
        dispatcher: the kernel (its name labels it in profiles).
    """

    def __init__(self, dispatcher: Any) -> None:
        self.dispatcher = dispatcher
        self._key: tuple[Any, ...] | None = None
        self._held: tuple[Any, ...] = ()  # the records keyed by id stay alive
        self._fn: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        key = tuple(map(_type_key, args))
        if key != self._key or self._fn is None:
            self._fn = bind(self.dispatcher, *args)
            self._key = key
            self._held = tuple(a for a in args if isinstance(a, tuple))
        return self._fn(*args)


_BOUND: dict[Any, Bound] = {}


def bound(kernel_or_function: Any) -> Callable[..., Any]:
    """The process's :class:`Bound` of a kernel (one per kernel); anything else as it is
    (a function standing in for a kernel: a test's, a profiler's wrapper)."""
    if not isinstance(kernel_or_function, numba.core.dispatcher.Dispatcher):
        f: Callable[..., Any] = kernel_or_function
        return f
    b = _BOUND.get(kernel_or_function)
    if b is None:
        b = _BOUND[kernel_or_function] = Bound(kernel_or_function)
    return b


#: Whether :func:`cycle_count` reads a hardware counter here: x86's time-stamp counter, which
#: user code may read and which ticks at a constant rate. Elsewhere LLVM's counter may trap
#: or read 0, so callers skip their profile.
HAS_CYCLE_COUNTER = platform.machine().lower() in ("x86_64", "amd64")


@intrinsic_returning(int)
def _read_cycle_counter(typingctx: Any) -> Any:
    sig = types.int64()

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.IntType(64), []), "llvm.readcyclecounter")
        return builder.call(fn, [])

    return sig, codegen


@kernel
def cycle_count() -> int:
    """The CPU's cycle counter (about 25 cycles to read; only where
    :data:`HAS_CYCLE_COUNTER`): a compiled loop times its own stages with it, and the caller
    converts counts to seconds against its wall clock over the same run."""
    return _read_cycle_counter()


class CompileWatch:
    """What numba compiles while this watch is on (``with CompileWatch(show=print): …``).

    numba compiles a kernel on its first call when the cache holds none for its types (a
    first run after an install or an upgrade: about a minute for a world); the watch counts
    those compilations and their wall time (nested ones once), and, with ``show``, announces
    the first one (naming the cache folder) and then reports the progress every
    ``every_s`` seconds from a background thread, so a first run does not look like a hang.

    Attributes:
        kernels: compilations finished.
        seconds: wall time spent compiling [s].
    """

    def __init__(self, show: Callable[[str], None] | None = None, every_s: float = 5.0) -> None:
        self.show = show
        self.every_s = every_s
        self.kernels = 0
        self.seconds = 0.0
        self._depth = 0
        self._t0 = 0.0
        self._current = ""
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        watch = self

        class _Listener(numba_event.Listener):
            def on_start(self, event: Any) -> None:
                watch._started(event.data["dispatcher"].py_func.__name__)

            def on_end(self, event: Any) -> None:
                watch._ended()

        self._listener = _Listener()

    def __enter__(self) -> CompileWatch:
        numba_event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc: object) -> None:
        numba_event.unregister("numba:compile", self._listener)
        self._wake.set()
        if self._thread is not None:
            self._thread.join()

    def _started(self, name: str) -> None:
        with self._lock:
            self._current = name
            self._depth += 1
            if self._depth > 1:
                return
            self._t0 = time.perf_counter()
            first = self._thread is None and self.show is not None
        if first:
            assert self.show is not None
            self.show(f"compiling uavmpc's kernels for this machine (once; cached in "
                      f"{CACHE_DIR})")
            self._thread = threading.Thread(target=self._report, daemon=True)
            self._thread.start()

    def _ended(self) -> None:
        with self._lock:
            self.kernels += 1
            self._depth -= 1
            if self._depth == 0:
                self.seconds += time.perf_counter() - self._t0

    def elapsed_s(self) -> float:
        """Wall time spent compiling so far, including a compilation in progress [s]."""
        with self._lock:
            running = time.perf_counter() - self._t0 if self._depth > 0 else 0.0
            return self.seconds + running

    def _report(self) -> None:
        # Also says when the compilation is over: a slow flight after it is not compiling.
        said_busy = True  # the announcement of the first compilation
        while not self._wake.wait(self.every_s):
            with self._lock:
                busy, name, done = self._depth > 0, self._current, self.kernels
            if self.show is None:
                continue
            if busy:
                self.show(f"  compiling: {done} kernels done, now {name}, "
                          f"{self.elapsed_s():.0f} s so far")
            elif said_busy:
                self.show(f"  compiled {done} kernels in {self.elapsed_s():.0f} s; running")
            said_busy = busy
