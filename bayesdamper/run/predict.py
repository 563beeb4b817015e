"""The ``predict`` job: a calibrated damper driven by a displacement history, and the leave-one-test-out check
of its predictions.

``bayesdamper predict RESULTS --input FILE.csv --out OUT`` reads the calibration an ``identify`` (eq. (7):
``calibration.nc``) or ``diagnose`` run (eq. (7) with the diagnosed effects: ``calibration-final.nc``) left in
RESULTS, reconstructs the history's input as for a measured record (:mod:`bayesdamper.io.reconstruct`), and writes
``prediction.csv`` (time, displacement, the force's predictive median and its 50 % and 90 % bands, and the measured
force if the file has one), ``prediction.json`` (operating speed, calibrated range, the model, seed, versions and
input hashes, and the coverage and J against a measured force) and ``figures/prediction.{png,pdf}``. What a
prediction is: :mod:`bayesdamper.inference.calibration`.
"""

from __future__ import annotations

import hashlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.inference.calibration import QUANTILES, Calibration
from bayesdamper.io.dataset import TEMPERATURE_COLUMN
from bayesdamper.io.outputs import atomic_write_bytes, atomic_write_json, versions

#: The calibration of eq. (7) (``identify``, and ``diagnose`` for its baseline).
CALIBRATION_FILE = "calibration.nc"
#: The calibration of eq. (7) with the effects ``diagnose`` selected (only when it selected any).
FINAL_CALIBRATION_FILE = "calibration-final.nc"
#: Draws of a prediction.
N_DRAWS = 200
#: Draws of each left-out test's prediction in the leave-one-test-out check.
LOO_DRAWS = 100
#: Quantile of |velocity| that is a history's operating speed (the speed of a window of cycles).
SPEED_QUANTILE = 0.99


@dataclass
class Prediction:
    """A calibrated damper's force for one displacement history.

    Attributes
    ----------
    time, displacement : ndarray, shape (n,)
    quantiles : ndarray, shape (5, n)
        The force's predictive 5, 25, 50, 75 and 95 % quantiles [N] (model draws plus measurement noise).
    measured : ndarray or None
        The measured force [N], if the history has one.
    speed : float
        Operating speed [m/s] (99th percentile of |velocity|).
    info : dict
        Model, calibrated speed range, extrapolation, failed solves, reconstruction, scores.
    """

    time: np.ndarray
    displacement: np.ndarray
    quantiles: np.ndarray
    measured: np.ndarray | None
    speed: float
    info: dict

    @property
    def median(self) -> np.ndarray:
        return self.quantiles[2]

    def csv_bytes(self) -> bytes:
        cols = ["time_s", "displacement_m", "force_median_N", "force_lo50_N", "force_hi50_N", "force_lo90_N",
                "force_hi90_N"]
        q = self.quantiles
        data = [self.time, self.displacement, q[2], q[1], q[3], q[0], q[4]]
        if self.measured is not None:
            cols.append("force_measured_N")
            data.append(self.measured)
        arr = np.column_stack(data)
        lines = [",".join(cols)] + [",".join(f"{x:.9g}" for x in row) for row in arr]
        return ("\n".join(lines) + "\n").encode()


def scores(measured: np.ndarray, quantiles: np.ndarray) -> dict:
    """Share of measured samples inside the 90 % and 50 % bands and J (eq. (9)) of the median."""
    from bayesdamper.inference.likelihood import cost_j

    f = np.asarray(measured, float)
    return {"coverage_90": float(np.mean((f >= quantiles[0]) & (f <= quantiles[4]))),
            "coverage_50": float(np.mean((f >= quantiles[1]) & (f <= quantiles[3]))),
            "J_median": float(cost_j(quantiles[2], f))}


def history_drive(record):
    """The model's input for a history: its reconstruction (a piecewise polynomial), the operating speed [m/s],
    the velocity at its start [m/s] and the reconstruction's description."""
    from bayesdamper.io.reconstruct import reconstruct_input
    from bayesdamper.io.windows import reconstructed_drive

    try:
        rec = reconstruct_input(record.time, record.displacement, velocity=record.velocity)
    except DataError as err:
        raise DataError(f"{record.path}: {err}") from None
    drive = reconstructed_drive(rec)
    v = rec.velocity(record.time)
    return drive, float(np.quantile(np.abs(v), SPEED_QUANTILE)), float(v[0]), rec.as_dict()


def process_map(workers: int):
    """``map_fn`` of :meth:`Calibration.simulate`: the package's process pool, or None for serial solves."""
    if workers <= 1:
        return None
    from bayesdamper.run.stages import run_tasks

    return lambda f, tasks: run_tasks(f, tasks, workers, lambda *a: None)


def record_covariates(records) -> tuple[dict | None, str | None]:
    """The drift law's covariate of a data set's records: each record's mean temperature, where every record has
    a ``temperature_C`` column; else None."""
    if records and all(getattr(r, "temperature", None) is not None for r in records):
        return {r.name: float(np.mean(r.temperature)) for r in records}, TEMPERATURE_COLUMN
    return None, None


def predict_history(cal: Calibration, time: np.ndarray, drive, speed: float, start_velocity: float, *,
                    measured: np.ndarray | None = None, n_draws: int = N_DRAWS, seed: int = 0,
                    workers: int = 1, covariate: float | None = None) -> Prediction:
    """Run a calibration on an input: draws of a new test at ``speed`` (and ``covariate``, where the law has one;
    default its calibrated mean), simulated, plus measurement noise."""
    time = np.asarray(time, float)
    forces, _, failed = cal.simulate(time, drive, speed, start_velocity, n_draws, seed, process_map(workers),
                                     covariate)
    if len(forces) == 0:
        raise DataError(f"every one of the {n_draws} draws failed to solve on this history")
    rate = 1.0 / float(np.median(np.diff(time))) if time.size > 1 else 0.0
    sims = forces + cal.noise(len(forces), time.size, rate, seed)
    q = np.quantile(sims, QUANTILES, axis=0)
    lo, hi = cal.hierarchy.speed_range
    info = {"model": cal.model, "effects": cal.effects, "n_draws": n_draws, "failed_solves": int(failed),
            "speed_m_s": speed, "calibrated_speed_range_m_s": [lo, hi], "extrapolated": not lo <= speed <= hi,
            "start_velocity_m_s": start_velocity, "seed": seed,
            "noise": {"sigma_N": cal.noise_sigma_N, "phi_at_calibration_rate": cal.noise_phi,
                      "calibration_rate_Hz": cal.sample_rate_Hz}}
    law_cov = cal.hierarchy.covariate
    if law_cov is not None:
        value = law_cov["c_c"] if covariate is None else float(covariate)
        c0, c1 = law_cov["range"]
        info["covariate"] = {"name": law_cov["name"], "value": value, "calibrated_range": [c0, c1],
                             "source": "the calibration's mean" if covariate is None else "the history",
                             "extrapolated": not c0 <= value <= c1}
    if measured is not None and np.all(np.isfinite(measured)):
        info.update(scores(measured, q))
    return Prediction(time, np.asarray(drive.displacement(time), float), q,
                      None if measured is None or not np.all(np.isfinite(measured)) else np.asarray(measured),
                      speed, info)


def calibration_path(results: str | Path, model: str = "auto") -> Path:
    """The calibration file of a results folder: ``final`` (with the diagnosed effects), ``baseline`` (eq. (7))
    or ``auto`` (the final one where ``diagnose`` selected effects, else eq. (7))."""
    folder = Path(results)
    if model not in ("auto", "final", "baseline"):
        raise SettingsError(f"--model must be auto, final or baseline, got {model!r}")
    if not folder.is_dir():
        raise DataError(f"{folder}: no such results folder (run bayesdamper identify, diagnose or report first)")
    final, base = folder / FINAL_CALIBRATION_FILE, folder / CALIBRATION_FILE
    if model == "final" and not final.exists():
        raise DataError(f"{folder}: no {FINAL_CALIBRATION_FILE} (diagnose selected no effect, or has not run)")
    if model in ("final", "auto") and final.exists():
        return final
    if not base.exists():
        raise DataError(f"{folder}: no {CALIBRATION_FILE}: not the output folder of bayesdamper identify, diagnose "
                        "or report")
    return base


def load_calibration(path: Path) -> Calibration:
    """Read a calibration file, or a one-line DataError."""
    try:
        return Calibration.load(path)
    except (OSError, KeyError, ValueError, TypeError) as err:
        raise DataError(f"{path}: not a readable calibration ({type(err).__name__}: "
                        f"{str(err).splitlines()[0] if str(err) else 'no detail'})") from None


def predict(results: str | Path, input: str | Path, out: str | Path | None = None, *, n_draws: int = N_DRAWS,
            seed: int = 0, workers: int = 1, model: str = "auto", figures: bool = True,
            quiet: bool = False) -> Prediction:
    """``bayesdamper predict``: the calibrated damper of ``results`` driven by the history in ``input``.

    Parameters
    ----------
    results : path
        Output folder of ``identify``, ``diagnose`` or ``report``.
    input : path
        CSV with ``time_s`` and ``displacement_m`` (optional ``force_N``: the measured force to score against;
        optional ``velocity_m_s``).
    out : path, optional
        Folder for ``prediction.csv``, ``prediction.json`` and the figure; nothing is written without it.
    n_draws, seed, workers : int
        Predictive draws, their seed, and worker processes of the simulations.
    model : {"auto", "final", "baseline"}
        Which calibration (see :func:`calibration_path`).

    Returns
    -------
    Prediction
        A history outside the calibrated speed range is predicted with the law extrapolated, and says so
        (``info["extrapolated"]``, a line on stderr).
    """
    from bayesdamper.io.dataset import load_history

    if not (isinstance(n_draws, int) and n_draws >= 10):
        raise SettingsError(f"--draws must be an integer >= 10 (quantiles of fewer draws are noise), got {n_draws}")
    path = calibration_path(results, model)
    cal = load_calibration(path)
    record = load_history(input)
    drive, speed, v0, recon = history_drive(record)
    if out is not None:
        out_dir = Path(out)
        if out_dir.exists() and not out_dir.is_dir():
            raise DataError(f"{out_dir}: exists and is not a folder")
    covariate = None
    if cal.hierarchy.covariate is not None and cal.hierarchy.covariate["name"] == TEMPERATURE_COLUMN \
            and record.temperature is not None:
        covariate = float(np.mean(record.temperature))
    pred = predict_history(cal, record.time, drive, speed, v0, measured=record.force, n_draws=n_draws, seed=seed,
                           workers=workers, covariate=covariate)
    lo, hi = pred.info["calibrated_speed_range_m_s"]
    if pred.info["extrapolated"] and not quiet:
        print(f"bayesdamper predict: {record.path}: operating speed {1e3 * speed:.3g} mm/s is outside the calibrated "
              f"range {1e3 * lo:.3g}-{1e3 * hi:.3g} mm/s: the drift law is extrapolated", file=sys.stderr)
    cov = pred.info.get("covariate")
    if cov and not quiet and (cov["extrapolated"] or covariate is None):
        c0, c1 = cov["calibrated_range"]
        print(f"bayesdamper predict: {record.path}: {cov['name']} {cov['value']:.4g} ("
              + ("the calibration's mean: the history has no such column" if covariate is None else
                 f"outside the calibrated range {c0:.4g}-{c1:.4g}: the drift law is extrapolated") + ")",
              file=sys.stderr)
    pred.info.update({"input": str(record.path), "input_sha256": record.sha256, "calibration": str(path),
                      "calibration_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                      "reconstruction": recon, "versions": versions(), "calibration_provenance": cal.provenance})
    if out is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out_dir / "prediction.csv", pred.csv_bytes())
        if figures:
            from bayesdamper.report.prediction import prediction_figure

            pred.info["figures"] = [str(p) for p in prediction_figure(pred, out_dir / "figures" / "prediction")]
        atomic_write_json(out_dir / "prediction.json", pred.info)
        if not quiet:
            msg = f"prediction written to {out_dir / 'prediction.csv'}"
            if "coverage_90" in pred.info:
                msg += (f" (measured force inside the 90 % band at {100 * pred.info['coverage_90']:.0f} % of samples,"
                        f" J of the median {pred.info['J_median']:.4f})")
            print(msg)
    return pred


def _fit_calibration(results: list, damper, effects: dict | None, *, seed: int, provenance: dict,
                     records=()) -> tuple[Calibration | None, dict]:
    """The calibration of ``results`` (:func:`~bayesdamper.inference.calibration.calibrate`) and the seconds it
    took; ``(None, {"fitted": False, "reason": ...})`` where there are too few windows or speeds for a law."""
    from bayesdamper.inference.calibration import calibrate

    t0 = time.perf_counter()
    try:
        covariates, name = record_covariates(list(records))
        cal = calibrate(results, damper, effects, seed=seed, provenance=provenance, covariates=covariates,
                        covariate_name=name)
    except ValueError as err:
        return None, {"fitted": False, "reason": str(err)}
    return cal, {"wall_s": time.perf_counter() - t0}


def _save_calibration(path: Path, cal: Calibration | None, fit: dict, credible_mass: float,
                      progress=None) -> dict:
    """Write a fitted calibration to ``path`` and return the drift law's summary for the results' JSON (``fit``
    from :func:`_fit_calibration`; an unfitted one is returned as it is)."""
    if cal is None:
        return fit
    cal.save(path)
    out = {"fitted": True, "file": path.name, "model": cal.model, **cal.hierarchy.summary(credible_mass),
           "prediction_noise": {"sigma_N": cal.noise_sigma_N, "phi": cal.noise_phi,
                                "rate_Hz": cal.sample_rate_Hz},
           "wall_s": fit["wall_s"]}
    if progress is not None:
        sm = out["sampling"]
        progress(f"drift law ({cal.model}): {len(cal.hierarchy.windows)} windows, "
                 f"{'converged' if sm['converged'] else 'NOT converged'} (R-hat {sm['rhat_max']:.3f}), "
                 f"{out['wall_s']:.1f} s")
    return out


def write_calibration(path: Path, results: list, damper, effects: dict | None, *, seed: int, credible_mass: float,
                      provenance: dict, progress=None, records=()) -> tuple[Calibration | None, dict]:
    """Fit the calibration of ``results`` (:func:`~bayesdamper.inference.calibration.calibrate`), write it to
    ``path`` and return it with the drift law's summary for the results' JSON; where there are too few windows or
    speeds for a law, nothing is written, no calibration is returned and the summary says why."""
    cal, fit = _fit_calibration(results, damper, effects, seed=seed, provenance=provenance, records=records)
    return cal, _save_calibration(path, cal, fit, credible_mass, progress)


#: What the tasks of :func:`calibrate_and_check` read (forked workers inherit it; not sent with every task).
_CHECK: dict = {}


def _check_calibration_task(key: str) -> tuple[Calibration | None, dict]:
    """Worker task of :func:`calibrate_and_check`: the calibration of the job ``key``."""
    c = _CHECK
    return _fit_calibration(c["results"][key], c["damper"], c["effects"][key], seed=c["seed"],
                            provenance=c["provenance"], records=c["records_seq"])


def _check_loo_task(task) -> tuple[dict | None, float]:
    """Worker task of :func:`calibrate_and_check`: one test left out of a calibration (its row) and its seconds."""
    cal, test = task
    c = _CHECK
    t0 = time.perf_counter()
    row = _loo_row(cal, cal.windows, test, c["by_test"][test], c["records"], seed=c["seed"], n_draws=LOO_DRAWS,
                   workers=1)
    return row, time.perf_counter() - t0


def calibrate_and_check(out_dir: Path, ds, windows: list, base: list, final: list, effects: dict, *, seed: int,
                        credible_mass: float, provenance: dict, workers: int, progress) -> dict:
    """The calibrations of a diagnosis (eq. (7), and with the selected ``effects`` if any) written to ``out_dir``,
    and the leave-one-test-out check of both: ``{"drift_model_before", "drift_model_after", "prediction_check"}``.
    A final calibration of an earlier run is removed when no effect is selected.

    The calibrations, then every (calibration, test left out) pair, are tasks (:func:`_check_calibration_task`,
    :func:`_check_loo_task`) of :func:`~bayesdamper.run.stages.run_tasks`, on ``workers`` processes. Every task is
    seeded as in a run of its own, so the results do not depend on ``workers``; a model's ``wall_s`` is the seconds
    its tests' tasks took, summed.
    """
    out = {}
    records = {r.name: r for r in ds.records}
    check = {"n_draws": LOO_DRAWS, "method": "each test's windows left out of the drift law (importance "
             "re-weighting of its hyper-posterior, or a re-fit); the whole test record predicted from its measured "
             "displacement; flow coefficients and measurement noise from all tests", "models": {}}
    final_path = Path(out_dir) / FINAL_CALIBRATION_FILE
    jobs = [("before", "eq. (7)", Path(out_dir) / CALIBRATION_FILE, base, None)]
    if effects:
        jobs.append(("after", "with the diagnosed effects", final_path, final, effects))
    elif final_path.exists():
        final_path.unlink()
    by_test = _windows_by_test(windows)
    tests = [t for t in by_test if t in records]

    from bayesdamper.run.stages import run_tasks

    def quiet(*_):
        pass

    global _CHECK
    _CHECK = {"results": {j[0]: j[3] for j in jobs}, "effects": {j[0]: j[4] for j in jobs}, "damper": ds.damper,
              "seed": seed, "provenance": provenance, "records_seq": list(ds.records), "records": records,
              "by_test": by_test}
    try:
        fits = run_tasks(_check_calibration_task, [j[0] for j in jobs], workers, quiet)
        cals = _save_calibrations(jobs, fits, out, credible_mass, progress)
        loo = run_tasks(_check_loo_task, [(cals[key], t) for key in cals for t in tests], workers, quiet)
    finally:
        _CHECK = {}
    done = iter(loo)
    for key, label, *_ in jobs:
        if key not in cals:
            continue
        parts = [next(done) for _ in tests]
        model_rows = [row for row, _ in parts if row is not None]
        check["models"][label] = {"model": cals[key].model, "rows": model_rows,
                                  "wall_s": sum(sec for _, sec in parts), **_pooled(model_rows)}
        if progress is not None and model_rows:
            progress(check_line(cals[key].model, check["models"][label], len(model_rows)))
    out["prediction_check"] = check
    return out


def _save_calibrations(jobs: list, fits: list, out: dict, credible_mass: float, progress) -> dict:
    """Write each job's fitted calibration (:func:`_save_calibration`), its summary into ``out``
    (``drift_model_<key>``); returns the fitted ones by key."""
    cals = {}
    for (key, _, path, _, _), (cal, fit) in zip(jobs, fits, strict=True):
        out[f"drift_model_{key}"] = _save_calibration(path, cal, fit, credible_mass, progress)
        if cal is not None:
            cals[key] = cal
    return cals


def check_line(model: str, pooled: dict, n_tests: int) -> str:
    """One progress line of the prediction check of ``model``; ``pooled`` is its entry (``_pooled`` and
    ``wall_s``), which holds no score when no test could be predicted without it."""
    scored = (f"measured inside the 90 % band {100 * pooled['coverage_90']:.0f} % of samples, median J "
              f"{pooled['J_median']:.4f}" if "coverage_90" in pooled else
              "no test scored (too few tests left for a law, or every solve failed)")
    return f"prediction check ({model}): {scored}, {n_tests} tests left out, {pooled['wall_s']:.0f} s"


def _pooled(rows: list[dict]) -> dict:
    if not rows:
        return {}
    return {k: float(np.median([r[k] for r in rows if k in r])) for k in ("coverage_90", "coverage_50", "J_median")
            if any(k in r for r in rows)}


def _windows_by_test(windows: list) -> dict[str, list]:
    """The windows of each test, tests in the order of their first window."""
    by_test: dict[str, list] = {}
    for w in windows:
        by_test.setdefault(w.test, []).append(w)
    return by_test


def leave_one_test_out(cal: Calibration, windows_draws: list, windows: list, records: dict, *, seed: int = 0,
                       n_draws: int = LOO_DRAWS, workers: int = 1) -> list[dict]:
    """The check that predictions are honest: for every test, the law without that test's windows
    (:func:`~bayesdamper.inference.hierarchy.leave_out`) predicts the whole test record from its measured
    displacement; the rows give the share of samples inside the 90 % and 50 % bands and J of the median.

    ``windows_draws`` are the law's windows (:func:`~bayesdamper.inference.calibration.calibration_windows`),
    ``windows`` the data set's windows (their ``drive`` is the record's input), ``records`` the records by name.
    The flow coefficients and the measurement noise keep every test (they come from the plateaus of all tests, or
    from all windows): only the law of α_V and p_R leaves the test out.
    """
    rows = []
    for test, ws in _windows_by_test(windows).items():
        row = _loo_row(cal, windows_draws, test, ws, records, seed=seed, n_draws=n_draws, workers=workers)
        if row is not None:
            rows.append(row)
    return rows


def _loo_row(cal: Calibration, windows_draws: list, test: str, ws: list, records: dict, *, seed: int,
             n_draws: int, workers: int) -> dict | None:
    """The row of :func:`leave_one_test_out` of ``test`` (its windows ``ws``), None where it has no record."""
    from dataclasses import replace

    from bayesdamper.inference.hierarchy import leave_out

    rec = records.get(test)
    if rec is None:
        return None
    ids = {w.id for w in ws}
    speed = float(np.median([w.velocity for w in ws]))
    row = {"test": test, "speed_m_s": speed, "n_windows_left_out": len(ids)}
    try:
        law = leave_out(cal.hierarchy, windows_draws, test, seed=seed)
    except ValueError as err:  # too few tests without it for a law
        return row | {"law": f"none: {err}"}
    drive = ws[0].drive
    v0 = float(drive.velocity(rec.time[:1])[0])
    cov = float(np.mean(rec.temperature)) if cal.hierarchy.covariate is not None \
        and getattr(rec, "temperature", None) is not None else None
    try:
        p = predict_history(replace(cal, hierarchy=law), rec.time, drive, speed, v0, measured=rec.force,
                            n_draws=n_draws, seed=seed, workers=workers, covariate=cov)
    except DataError as err:  # every draw failed to solve
        return row | {"law": law.sampling.get("method", "re-fitted"), "failed": str(err)}
    lo, hi = law.speed_range
    return row | {"law": law.sampling.get("method", "re-fitted"), "extrapolated": not lo <= speed <= hi,
                  "failed_solves": p.info["failed_solves"],
                  **{k: p.info[k] for k in ("coverage_90", "coverage_50", "J_median") if k in p.info}}
