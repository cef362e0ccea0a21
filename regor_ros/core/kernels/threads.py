"""The threads the kernels run on: numba's OpenMP layer first, and numpy's BLAS kept on one thread
while a registration runs (``blas_on_one_thread``); ``JIT``, the options every kernel compiles with
(cached on disk, the GIL released)."""
from __future__ import annotations

import threading
from contextlib import contextmanager
from functools import lru_cache

import numba
from threadpoolctl import ThreadpoolController

JIT = dict(cache=True, nogil=True)
# OpenMP first: thread-safe (the node registers off its executor thread), and never the warning a
# too-old TBB (some pip environments carry one) prints when tried first
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


@lru_cache(maxsize=1)
def _numpy_blas() -> ThreadpoolController:
    """The BLAS libraries loaded (numpy's, scipy's), except the copy FAISS carries: FAISS finds
    the cells a map query probes, and on one thread it was slower."""
    blas = ThreadpoolController().select(user_api="blas")
    return blas.select(filepath=[lib.filepath for lib in blas.lib_controllers if "faiss" not in lib.filepath.lower()])


_blas_lock = threading.Lock()
_blas_users = 0
_blas_limit = None


@contextmanager
def blas_on_one_thread():
    """numpy's BLAS on one thread while registrations run (the first in limits, the last out
    restores). After a call OpenBLAS keeps its worker threads spinning, waiting for the next; on
    two cores they took a core from the compiled kernels and FAISS that came next, and a
    registration's products are too small
    to gain from a second thread."""
    global _blas_users, _blas_limit
    with _blas_lock:
        if _blas_users == 0:
            _blas_limit = _numpy_blas().limit(limits=1)
        _blas_users += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_users -= 1
            if _blas_users == 0:
                _blas_limit.restore_original_limits()


def threads() -> int:
    """The threads a registration's parallel work runs on (the kernels' own; ``regor-batch``
    gives each worker its share)."""
    return numba.get_num_threads()
