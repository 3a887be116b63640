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

import hashlib
import os
import platform
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

F = TypeVar("F", bound=Callable[..., Any])

#: Let LLVM reorder sums (vectorised dot products) and fuse multiply-adds, but keep NaN/inf
#: semantics: the kernels rely on isnan/isfinite to reject bad data.
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}
#: :data:`FASTMATH` without reordering sums: for a kernel whose sums must come out bit for bit
#: as another kernel's that LLVM does not reorder.
FASTMATH_ORDERED = {"contract", "nsz", "arcp"}


_IMPORT = re.compile(r"^\s*(?:from|import)\s+(uavmpc(?:\.\w+)*)", re.MULTILINE)


def _compiled_sources(root: Path) -> list[Path]:
    """The modules compiled code can depend on: those that use this module (they hold
    kernels) and, transitively, every package module they import (constants and helpers a
    kernel reads are frozen into its machine code). A driver or an application outside that
    closure can change without a recompilation."""
    files = {p: p.read_text(encoding="utf-8") for p in root.rglob("*.py")}

    def resolve(name: str) -> list[Path]:
        parts = name.split(".")[1:]
        for n in range(len(parts), -1, -1):
            base = root.joinpath(*parts[:n])
            for cand in (base.with_suffix(".py"), base / "__init__.py"):
                if cand in files:
                    return [cand]
        return []

    todo = [p for p, text in files.items() if "uavmpc.jit" in text]
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


def kernel(fn: F | None = None, /, **options: Any) -> Any:
    """``numba.njit(cache=True, **options)`` with the cache in :data:`CACHE_DIR`.

    Use as ``@kernel`` or ``@kernel(fastmath=FASTMATH)``.
    """

    def decorate(f: F) -> F:
        saved = numba.config.CACHE_DIR
        numba.config.CACHE_DIR = CACHE_DIR
        try:
            compiled: F = numba.njit(cache=True, **options)(f)  # numba is untyped
            return compiled
        finally:
            numba.config.CACHE_DIR = saved

    return decorate(fn) if fn is not None else decorate


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


#: Whether :func:`cycle_count` reads a hardware counter here: x86's time-stamp counter, which
#: user code may read and which ticks at a constant rate. Elsewhere LLVM's counter may trap
#: or read 0, so callers skip their profile.
HAS_CYCLE_COUNTER = platform.machine().lower() in ("x86_64", "amd64")


@intrinsic
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
