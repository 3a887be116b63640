"""The one way uavmpc compiles a kernel: ``@kernel`` (numba ``njit``, cached on disk).

numba's on-disk cache checks only the source file of the function it caches: a kernel that
calls a kernel from another file would keep running stale machine code after that other file
changed. uavmpc's kernels call each other across its stages (the world's batched tick calls the
tracker, the SE(3) law and the plant), so every kernel of the package is cached in a folder
named after a hash of *all* the package's sources: any edit anywhere starts a fresh cache, and
an unchanged install shares one cache between processes (campaign workers, nodes).

The folder is ``$UAVMPC_CACHE_DIR`` or ``~/.cache/uavmpc/numba``, one sub-folder per hash; older
sub-folders are left for the user to delete. Only uavmpc's kernels use it: numba's global cache
setting is restored right after each decoration.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

#: Let LLVM reorder sums (vectorised dot products) and fuse multiply-adds, but keep NaN/inf
#: semantics: the kernels rely on isnan/isfinite to reject bad data.
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}


def _sources_hash() -> str:
    root = Path(__file__).resolve().parent
    digest = hashlib.sha1(usedforsecurity=False)
    for path in sorted(root.rglob("*.py")):
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
            return numba.njit(cache=True, **options)(f)  # type: ignore[no-any-return]
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
    return dispatcher.compile(signature)  # type: ignore[no-any-return]
