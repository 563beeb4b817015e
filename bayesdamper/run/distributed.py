"""Stage 2 on a Dask distributed cluster (``bayesdamper identify --scheduler ADDRESS``).

The tasks are the same per-transient tasks the local process pool runs
(:func:`bayesdamper.inference.identify.identify_window`); each carries its transient's data arrays, the
damper constants, the stage-1 coefficients, the settings and the run seed, so a worker needs only the
``bayesdamper`` package, not the data files. A worker writes the transient's NetCDF posterior into
a private temporary folder and returns its bytes; the client writes them atomically into
``OUT/posteriors`` as each task finishes, so an interrupted run keeps every finished transient.
Task seeds depend only on the run seed and the segment id, so results equal the local run's.

Dask is optional (``pip install 'bayesdamper[distributed]'``) and imported only here, lazily.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from bayesdamper.core.errors import SettingsError
from bayesdamper.io.outputs import atomic_write_bytes

#: Seconds to wait for the scheduler before giving up.
CONNECT_TIMEOUT_S = 20.0

#: Extra that installs Dask distributed.
INSTALL_HINT = "pip install 'bayesdamper[distributed]'"


def _dask():
    try:
        import dask.distributed as dd
    except ImportError as err:
        raise SettingsError(f"--scheduler: dask.distributed is not installed ({err}); "
                            f"{INSTALL_HINT}") from None
    return dd


def check_available() -> None:
    """Raise SettingsError (one line) if Dask distributed cannot be imported."""
    _dask()


def connect(address: str, timeout: float = CONNECT_TIMEOUT_S):
    """A ``dask.distributed.Client`` connected to the scheduler at ``address`` (e.g. ``tcp://host:8786``).

    Raises
    ------
    SettingsError
        If Dask is missing or the scheduler cannot be reached (one line).
    """
    dd = _dask()
    try:
        return dd.Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        msg = " ".join(str(err).split()) or type(err).__name__
        raise SettingsError(f"--scheduler: cannot connect to {address}: {msg}") from None


def _remote_identify(task: tuple) -> tuple:
    """Run one window on a worker; return ``(WindowResult, NetCDF bytes or None)``."""
    from bayesdamper.inference.identify import identify_window

    tr, damper, flow, settings, seed, nc, prov, draws, prior, effects, start = task
    if nc is None:
        return identify_window(tr, damper, flow, settings, seed, None, prov, static_draws=draws,
                               prior=prior, effects=effects, start=start), None
    with tempfile.TemporaryDirectory(prefix="bayesdamper-") as tmp:
        local = Path(tmp) / Path(nc).name
        res = identify_window(tr, damper, flow, settings, seed, local, prov, static_draws=draws, prior=prior,
                              effects=effects, start=start)
        return res, local.read_bytes()


def map_transients(client, tasks: Sequence[tuple], on_done: Callable[[int, object, int], None]) -> list:
    """Run the per-transient ``tasks`` on the cluster; results in task order.

    Each task is the tuple :func:`bayesdamper.run.stages.identify_all` builds; its sixth item is the
    NetCDF path on *this* machine (or None). ``on_done(index, result, n_done)`` is called as tasks
    finish, after the result's NetCDF (if any) has been written.
    """
    dd = _dask()
    futures = client.map(_remote_identify, list(tasks), pure=False)
    index = {f.key: i for i, f in enumerate(futures)}
    results: list = [None] * len(futures)
    try:
        for done, fut in enumerate(dd.as_completed(futures, loop=client.loop), 1):
            i = index[fut.key]
            res, nc_bytes = fut.result()
            if nc_bytes is not None:
                atomic_write_bytes(Path(tasks[i][5]), nc_bytes)
            results[i] = res
            on_done(i, res, done)
    finally:
        client.cancel([f for f in futures if not f.done()])
    return results
