"""Every ArviZ call of the package lives here, so a move to ArviZ 1.x touches one file.

Convergence statistics (rank-normalised R-hat across independently started ensembles, bulk ESS) and
the posterior store: one NetCDF file per transient holding the posterior, sample statistics, the
observed data and the provenance (seed, settings, package versions, input hashes).
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    import arviz as az


def rhat_across_ensembles(chain: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat per parameter, with each *ensemble* as one chain.

    Parameters
    ----------
    chain : ndarray, shape (n_ensembles, n_steps, n_walkers, ndim)

    Returns
    -------
    ndarray, shape (ndim,)
    """
    e, t, w, d = chain.shape
    flat = chain.reshape(e, t * w, d)  # step-major: split halves are early vs late steps
    return np.array([float(az.rhat(flat[:, :, k], method="rank")) for k in range(d)])


def ess_bulk(chain: np.ndarray) -> np.ndarray:
    """Bulk effective sample size per parameter, each walker's trajectory as one chain.

    Parameters
    ----------
    chain : ndarray, shape (n_ensembles, n_steps, n_walkers, ndim)
    """
    e, t, w, d = chain.shape
    per_walker = chain.transpose(0, 2, 1, 3).reshape(e * w, t, d)
    return np.array([float(az.ess(per_walker[:, :, k], method="bulk")) for k in range(d)])


def to_inference_data(physical: np.ndarray, names: tuple[str, ...], log_prob: np.ndarray,
                      observed: dict[str, np.ndarray], constant: dict[str, np.ndarray],
                      attrs: dict) -> az.InferenceData:
    """Build the stored InferenceData of one transient.

    Parameters
    ----------
    physical : ndarray, shape (n_chains, n_draws, ndim)
        Posterior draws in physical units; chains are walkers (ensemble-major).
    names : tuple of str
        Parameter names, in the order of the last axis.
    log_prob : ndarray, shape (n_chains, n_draws)
    observed, constant : dict of name -> ndarray
        Measured force and the sample times etc.
    attrs : dict
        Provenance; values that are not strings are stored as JSON.
    """
    posterior = {n: physical[:, :, i] for i, n in enumerate(names)}
    flat_attrs = {k: v if isinstance(v, str) else json.dumps(v) for k, v in attrs.items()}
    with warnings.catch_warnings():  # chains are walkers: a short run has more of them than draws
        warnings.filterwarnings("ignore", message="More chains", category=UserWarning)
        idata = az.from_dict(posterior=posterior, sample_stats={"lp": log_prob}, observed_data=observed,
                             constant_data=constant)
    for group in idata.groups():
        idata[group].attrs.update(flat_attrs)
    return idata


def write_netcdf(idata: az.InferenceData, path: Path) -> None:
    """Write atomically: to a temporary file in the same folder, then rename over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        idata.to_netcdf(str(tmp), engine="h5netcdf")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def read_netcdf(path: Path) -> az.InferenceData:
    """Read a stored posterior."""
    return az.from_netcdf(str(path), engine="h5netcdf")


def provenance(idata: az.InferenceData) -> dict:
    """The provenance attributes of a stored posterior, JSON values decoded."""
    out = {}
    for k, v in idata.posterior.attrs.items():
        try:
            out[k] = json.loads(v)
        except (TypeError, ValueError):
            out[k] = v
    return out


def read_transient(path: Path) -> dict:
    """Everything a stored transient holds, as plain arrays (for resuming a run without re-sampling).

    Returns
    -------
    dict
        ``names`` (tuple of str, the posterior variables in stored order), ``chains`` (ndarray,
        shape (n_chains, n_draws, ndim), physical units), ``time`` [s], ``force`` [N] (measured),
        ``band`` (ndarray, shape (3, n_times), predictive quantiles [N]) and ``ls_force`` [N] when the
        file has them (else None), and ``attrs`` (the provenance, JSON values decoded).
    """
    idata = read_netcdf(path)
    names = tuple(str(n) for n in idata.posterior.data_vars)
    chains = np.stack([np.asarray(idata.posterior[n].values, dtype=float) for n in names], axis=-1)
    const = idata.constant_data

    def _opt(name: str):
        return np.asarray(const[name].values, dtype=float) if name in const else None

    return {"names": names, "chains": chains, "time": np.asarray(const["time_s"].values, dtype=float),
            "force": np.asarray(idata.observed_data["force_N"].values, dtype=float),
            "band": _opt("band_N"), "ls_force": _opt("ls_force_N"), "displacement": _opt("displacement_m"),
            "attrs": provenance(idata)}


def write_draws(path: Path, draws: dict[str, np.ndarray], constant: dict[str, np.ndarray], attrs: dict) -> None:
    """Store draws that are not one window's posterior (a hyper-posterior, say), atomically: ``draws`` as the
    posterior group (each an array of shape (n_draws,), stored as one chain), ``constant`` as constant data and
    ``attrs`` (JSON values) on every group."""
    flat_attrs = {k: v if isinstance(v, str) else json.dumps(v) for k, v in attrs.items()}
    idata = az.from_dict(posterior={k: np.asarray(v, float)[None, :] for k, v in draws.items()},
                         constant_data=constant)
    for group in idata.groups():
        idata[group].attrs.update(flat_attrs)
    write_netcdf(idata, path)

