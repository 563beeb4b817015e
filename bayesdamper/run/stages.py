"""The steps every job shares: segmentation and stage 1 of the triangular tests (``segment_and_fit``), the
posterior of every window on worker processes (``identify_all``), drift with speed, and the table that describes
a data set.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bayesdamper.inference.identify import identify_window
from bayesdamper.inference.likelihood import LogPosterior, make_noise_model
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.inference.stage2 import StageTwoSettings, WindowResult
from bayesdamper.run.progress import Progress


def prepare(data_dir: str | Path, tmax: float):
    """Load, validate and segment a data set of triangular tests and fit stage 1: ``(ds, segs, transients,
    static)``. Raises DataError on bad input (a record that is not a triangular test included)."""
    from bayesdamper.run.plan import TWO_STAGE, plan_dataset

    plan = plan_dataset(data_dir, tmax, TWO_STAGE)
    return plan.ds, plan.segs, plan.windows, plan.static


def _worker(args) -> WindowResult:
    tr, damper, flow, settings, seed, nc, prov, draws, prior, effects, start = args
    return identify_window(tr, damper, flow, settings, seed, nc, prov, static_draws=draws, prior=prior,
                           effects=effects, start=start)


def _prior_of(prior, i: int):
    """The prior of the ``i``-th window: one for all, or one per window."""
    return prior[i] if isinstance(prior, list | tuple) else prior


def _pool(workers: int):
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx)


def warm_up_kernels(transient, damper, flow, settings: StageTwoSettings, prior=None) -> float:
    """Compile, or load from numba's on-disk cache, the kernels stage 2 calls; return the seconds spent.

    One log-posterior evaluation and one forward solve at the centre of the prior box, in this
    process. Run before a pool of worker processes starts, so the cache exists and forked workers
    inherit the compiled code instead of each compiling it again.
    """
    from bayesdamper.inference import joint
    from bayesdamper.inference.plateau_noise import PlateauNoise

    t0 = time.perf_counter()
    space = settings.space()
    centre = (space.lower + space.upper) / 2
    if flow is not None:
        problem = WindowProblem.from_window(transient, damper, flow)
        LogPosterior(problem, make_noise_model(settings.noise_model), space).batch(centre[None, :])
        problem.simulate_force(*space.to_physical(centre[None, :])[0, :2])
    if prior is None:
        prior = joint.StageOnePrior.flat(PlateauNoise(0.0, 1.0, 1, 0))
    jp = joint.JointProblem.from_window(transient, damper, prior)
    js = jp.space(settings.alpha_v_bounds, settings.p_r_bounds)
    joint.JointLogPosterior(jp, js).batch(((js.lower + js.upper) / 2)[None, :])
    return time.perf_counter() - t0


def identify_all(transients, damper, flow, settings: StageTwoSettings, seed: int, workers: int,
                 posterior_dir: Path | None, provenance: dict, progress: Progress,
                 static_draws: np.ndarray | None = None, *, client=None, prior=None,
                 effects=None, starts: list | None = None) -> list[WindowResult]:
    """Stage 2 for every transient, on ``workers`` processes or a Dask cluster; results in input order.

    ``prior`` (a :class:`~bayesdamper.inference.joint.StageOnePrior`) makes every posterior the joint one
    (flow coefficients and step Δp sampled). ``static_draws`` (rows of [C_L12, C_Q12, C_L21, C_Q21] from
    stage 1) switch on, for conditional posteriors, the check of how much the stage-1 uncertainty moves each
    transient's optimum. ``client`` (a connected ``dask.distributed.Client``) sends the tasks to its cluster
    instead of the local pool. ``effects`` (a :class:`~bayesdamper.physics.compose.ComposedEffects`) adds effects
    to every window's model, held at their values; ``starts`` (one dict per transient, or None) are further starts
    of their point fits with the effects (:func:`~bayesdamper.inference.identify.identify_window`'s ``start``).
    """
    tasks = [(tr, damper, flow, settings, seed,
              None if posterior_dir is None else posterior_dir / f"{tr.id}.nc", provenance, static_draws,
              _prior_of(prior, i), effects, None if starts is None else starts[i]) for i, tr in enumerate(transients)]
    def report(i: int, res: WindowResult, done: int) -> None:
        e = res.entry
        state = "converged" if e["converged"] else "NOT converged"
        progress(f"[{done}/{len(tasks)}] {e['id']}: {state}, R-hat {e['rhat_max']:.3f}, "
                 f"ESS {e['ess_bulk_min']:.0f}, τ_max {max(e['tau'].values()):.0f}, {e['wall_s']:.1f} s")
        progress.advance()

    if not tasks:
        return []
    if client is not None:
        from bayesdamper.run.distributed import map_transients

        return map_transients(client, tasks, report)
    if workers > 1 and len(tasks) > 1:
        # Compile (or load) the numba kernels once here: forked workers inherit them, and the on-disk
        # cache exists for spawned ones, instead of every worker compiling the same code at once.
        ready = warm_up_kernels(transients[0], damper, flow, settings, _prior_of(prior, 0))
        progress(f"numba kernels ready in {ready:.1f} s")
    return run_tasks(_worker, tasks, workers, report, before=lambda task: progress(f"sampling {task[0].id} ..."))


def run_tasks(worker, tasks: list, workers: int, report, before=None) -> list:
    """``worker(task)`` for every task, in this process or on a pool of ``workers`` processes; results in
    input order. ``report(i, result, n_done)`` is called as each finishes, ``before(task)`` before each
    serial one. An interruption or a failure cancels the queued tasks."""
    results: list = [None] * len(tasks)
    if workers <= 1 or len(tasks) <= 1:
        for i, task in enumerate(tasks):
            if before is not None:
                before(task)
            results[i] = worker(task)
            report(i, results[i], i + 1)
        return results
    with _pool(workers) as ex:
        futs = {ex.submit(worker, task): i for i, task in enumerate(tasks)}
        try:
            for done, fut in enumerate(as_completed(futs), 1):
                i = futs[fut]
                results[i] = fut.result()
                report(i, results[i], done)
        except BaseException:  # interrupted or failed: do not start the queued tasks
            ex.shutdown(wait=True, cancel_futures=True)
            raise
    return results


def data_table(ds, segs) -> dict:
    """The data set and its segmentation as plain values (for ``summary.json`` and the report)."""
    plateau = {(p.test, p.index): p for s in segs for p in (*s.plateaus, *s.unsettled)}
    left_out = {(p.test, p.index) for s in segs for p in s.unsettled}
    steps = []
    for s in segs:
        window = {w.index: w for w in s.transients}
        for st in s.steps:
            p = plateau.get((s.record.name, st.index))
            w = window.get(st.index)
            steps.append({
                "test": s.record.name, "index": int(st.index), "kind": st.kind,
                "direction": int(st.direction), "velocity_m_s": float(abs(st.velocity_after)),
                "t_step_s": float(st.time), "force_N": float(st.force),
                # the transient window's length: T_max, or less where the ramp ends first
                "window_s": float(w.time[-1] - w.t_step) if w is not None else None,
                "plateau_force_N": (float(np.sign(st.direction) * p.pressure_drop * ds.damper.piston_area)
                                    if p else None),
                # a plateau whose force still drifts is not a point of eq. (4): stage 1 takes the settled force its
                # approach extrapolates to (plateau_force_N is that force), or leaves it out
                "plateau_in_stage1": bool(p) and (s.record.name, st.index) not in left_out,
                "plateau_approach_tau_s": (float(p.approach_tau) if p and p.approach_tau is not None else None)})
    records = [{"name": r.name, "file": r.path.name, "n_samples": int(r.time.size),
                "sample_rate_Hz": float(r.sample_rate), "duration_s": r.duration, "sha256": r.sha256}
               for r in ds.records]
    return {"damper": asdict(ds.damper), "records": records, "steps": steps}
