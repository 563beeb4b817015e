"""One BLAS thread per process while a job runs its own worker processes.

bayesdamper parallelises over transients, folds and candidates with forked worker processes, one per core. The
OpenBLAS of numpy and scipy would add a thread pool per process on top (by default a thread per core) and
oversubscribe the cores: on the 2-core machine the residual-dynamics identification of rig-A took 48 s with
OpenBLAS's default threads and 11.5 s with one thread per process (2 worker processes). threadpoolctl, the
standard tool for this (maintained with joblib and scikit-learn), limits the pools of the running process, and
forked workers inherit the limit.
"""

from __future__ import annotations

from contextlib import contextmanager


@contextmanager
def one_blas_thread():
    """Limit the BLAS thread pools of this process (and of the workers it forks) to one thread; a context manager,
    or a decorator (``@one_blas_thread()``)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
