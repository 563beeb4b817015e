"""Coverage of whole-record intervals on sine, sweep and random records bayesdamper did not make (helper + script).

Data: :mod:`independent` and :mod:`independent_records` (scipy Radau at rtol 1e-10, eq. (7) re-derived from the
paper, no bayesdamper import). Each case (:data:`CASES`, one line each) is one data set of a few records of one
damper: rig-A (``RIG_A``, ``PAPER_FLOW``) with slow sines and sweeps in the paper's speed range (0.5-1.5 mm/s), or
the small MR-like damper (``SMALL``, ``SMALL_FLOW``) with sines of 0.5-5 Hz and 2-25 mm, sweeps and random inputs;
100 Hz to 1 kHz, 1 to 100 cycles, starts at speed (in the periodic steady state) or from rest, stops at rest
(smooth or abrupt), white or AR(1) force noise, displacement noise and ADC steps. Exact eq. (7) physics, no
friction, no offset: the force the toolkit sees is eq. (7) plus noise and ADC rounding. Truth drawn per record
from the seed: α_V log-uniform on [15, 150], p_R log-uniform on [0.05, 1] MPa, each flow coefficient the base
value times e^U(-0.3, 0.3).

Identification: ``bayesdamper identify DIR --out OUT --seed S --no-figures`` (a subprocess; this module imports
nothing from bayesdamper). Counted from ``OUT/summary.json``, per window (``segments`` entries): whether each
parameter's 90 % interval holds the record's truth, the relative 90 % width, convergence, and J_fit / J_truth,
J_truth being eq. (9) of the true (noise-free) force against the measured force over the window's raw samples.

Run as a script::

    python tests/record_coverage.py CASE [CASE ...] [--seeds 0,1] [--out DIR] [--json FILE]

The data-set generators for later tests are here too: :func:`make_conditions` (one damper at three charge
pressures) and the real-record habits :func:`make_mr_habits` and :func:`make_triangle_artefacts`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from independent import PAPER_FLOW, RIG_A, SMALL, SMALL_FLOW, sine_input, triangle_input  # noqa: E402
from independent_records import (  # noqa: E402
    GasCharge,
    Sensors,
    random_input,
    simulate_record,
    sine_at_speed,
    start_from_rest,
    stop_at,
    sweep_input,
    write_records,
)
from transient_coverage import AMPLITUDE, REST, SPEEDS  # noqa: E402

FLOW_NAMES = ("C_L12", "C_Q12", "C_L21", "C_Q21")
#: The flow coefficients' keys in a summary entry's ``flow``.
SUMMARY_FLOW = dict(zip(FLOW_NAMES, ("CL12", "CQ12", "CL21", "CQ21"), strict=True))
PARAMS = (*FLOW_NAMES, "alpha_V", "p_R_Pa")
DAMPERS = {"rig-A": (RIG_A, PAPER_FLOW), "small": (SMALL, SMALL_FLOW)}
#: Truth ranges: the paper's α_V (1/0.04-1/0.01 at its optimum, Fig. 6) and p_R (0.027-0.4 MPa) widened both ways.
ALPHA_V_RANGE = (15.0, 150.0)
P_R_RANGE = (5.0e4, 1.0e6)  # [Pa]
#: Each flow coefficient is the base value times e^U(-s, s): about ±35 %, as the whole-record coverage test.
FLOW_SPREAD = 0.3
#: Radau tolerance of the records: rtol 1e-9 is already within 1e-6 of 1e-11 (tests/test_independent.py).
RTOL = 1e-10
#: Pre-roll before a start at speed, in periods of the lowest frequency: eq. (7)'s slowest relaxation (rig-A,
#: soft gas at rest) is ~2 s against a period of 8-25 s there, and well under a period on the small damper.
PRE_ROLL_CYCLES = 2.0
#: A smooth stop decelerates over this fraction of the period of the motion's last frequency.
STOP_TAPER_CYCLES = 0.25
#: The clean (noise-free) force per record, next to the CSVs (the loader reads only damper.toml and *.csv).
CLEAN_FILE = "clean_force.npz"
#: z-score scale: a central 90 % interval of a Gaussian is ±1.645 sd.
Z90 = 1.6448536269514722
#: J ratio quantiles reported.
J_QUANTILES = (0.05, 0.5, 0.95)


@dataclass(frozen=True)
class Motion:
    """One record's motion. ``kind``: "sine" (``size`` amplitude [m], ``f_lo`` frequency [Hz], ``length``
    cycles), "sweep-linear" / "sweep-exponential" (amplitude [m], f_lo -> f_hi [Hz], ``length`` [s]), "random"
    (rms displacement [m] in the band [f_lo, f_hi], ``length`` [s]) or "random-v" (rms velocity [m/s])."""

    kind: str
    size: float
    f_lo: float
    f_hi: float = 0.0
    length: float = 3.0

    @property
    def seconds(self) -> float:
        """Duration of the motion [s]."""
        return self.length / self.f_lo if self.kind == "sine" else self.length

    @property
    def f_last(self) -> float:
        """Frequency at the end of the motion [Hz] (the band's top for random inputs)."""
        return self.f_lo if self.kind == "sine" else self.f_hi

    @property
    def label(self) -> str:
        """Short record-name part, e.g. ``sine_0p05Hz_2mm``."""
        f = f"{self.f_lo:g}Hz" if self.kind == "sine" else f"{self.f_lo:g}-{self.f_hi:g}Hz"
        size = f"{self.size * 1e3:g}mm" + ("_s" if self.kind == "random-v" else "")
        return f"{self.kind}_{f}_{size}".replace(".", "p")


def sine(amplitude: float, frequency: float, cycles: float) -> Motion:
    """A sine of ``amplitude`` [m] at ``frequency`` [Hz] for ``cycles`` periods."""
    return Motion("sine", amplitude, frequency, 0.0, cycles)


def sweep(amplitude: float, f0: float, f1: float, seconds: float, law: str = "linear") -> Motion:
    """A ``law`` chirp ("linear" or "exponential") of ``amplitude`` [m] from f0 to f1 [Hz] over ``seconds``."""
    return Motion(f"sweep-{law}", amplitude, f0, f1, seconds)


def random_motion(rms: float, f_lo: float, f_hi: float, seconds: float, of: str = "displacement") -> Motion:
    """Band-limited random motion in [f_lo, f_hi] [Hz] for ``seconds``, rms displacement [m] or velocity [m/s]."""
    return Motion("random" if of == "displacement" else "random-v", rms, f_lo, f_hi, seconds)


@dataclass(frozen=True)
class RecordCase:
    """One data set of the harness: damper, records, rate, sensors, start and stop."""

    damper: str  # "rig-A" or "small"
    motions: tuple[Motion, ...]  # one record each
    rate: float  # [Hz]
    force_sd: float  # marginal force-noise sd [N]
    force_phi: float = 0.0  # AR(1) coefficient (0: white)
    displacement_sd: float = 0.0  # [m]
    displacement_step: float = 0.0  # displacement ADC step [m]
    force_step: float = 0.0  # force ADC step [N]
    start: str = "speed"  # "speed": mid-stroke at peak speed, steady state; "rest": hold_s at rest, ramp-in
    stop: str = "none"  # "none", "smooth" or "abrupt": to rest at the end of the motion, then hold_s still
    hold_s: float = 2.0  # [s] at rest before a start from rest and after a stop
    velocity_sd: float | None = None  # a velocity channel with this noise sd [m/s]; None: no channel


SLOW = (sine(2e-3, 0.05, 2), sine(2e-3, 0.08, 3), sine(2e-3, 0.12, 4))  # peak speeds 0.63, 1.0, 1.5 mm/s
#: A 2 mm sine is shorter than a paper transient (~4.5 mm of stroke to the plateau at α_V 33, p_R 0.3 MPa): the
#: force at peak speed is 18 % below eq. (4) there, 96 % at α_V 15, p_R 50 kPa. These 5 mm sines reach it.
SLOW_5MM = (sine(5e-3, 0.016, 2), sine(5e-3, 0.032, 2), sine(5e-3, 0.048, 3))  # 0.5, 1.0, 1.5 mm/s
FAST = (sine(15e-3, 0.5, 5), sine(10e-3, 1.0, 5), sine(5e-3, 2.0, 8), sine(2e-3, 5.0, 20))  # 47-63 mm/s
SHORT = (sine(10e-3, 1.0, 4), sine(5e-3, 2.0, 6))

#: The cases (rig-A forces 1-6 kN, noise 10-20 N; small-damper forces 100-400 N, noise 1-3 N).
CASES = {
    "SLOW-W": RecordCase("rig-A", SLOW, 100.0, 15.0),
    "SLOW-AR": RecordCase("rig-A", SLOW, 250.0, 20.0, 0.95, displacement_sd=10e-6),
    "SLOW-1C": RecordCase("rig-A", tuple(sine(2e-3, m.f_lo, 1) for m in SLOW), 200.0, 10.0, force_step=5.0,
                          displacement_step=1e-6),
    "SLOW-DN": RecordCase("rig-A", SLOW, 100.0, 15.0, displacement_sd=30e-6),
    # an ordinary LVDT on the slow sines: 1 µm displacement noise, 10 N white force noise, 200 Hz
    "SLOW-LVDT": RecordCase("rig-A", SLOW, 200.0, 10.0, displacement_sd=1e-6),
    "SLOW-5MM": RecordCase("rig-A", SLOW_5MM, 100.0, 15.0, 0.9, displacement_step=2e-6),
    "SLOW-STOP": RecordCase("rig-A", SLOW, 200.0, 15.0, stop="abrupt", hold_s=6.0),
    "SLOW-REST": RecordCase("rig-A", SLOW, 100.0, 15.0, start="rest", hold_s=3.0),
    "SLOW-SWEEP": RecordCase("rig-A", (sweep(2e-3, 0.04, 0.15, 60.0), sweep(2e-3, 0.04, 0.15, 60.0, "exponential")),
                             100.0, 15.0, 0.9),
    "FAST": RecordCase("small", FAST, 500.0, 2.0),
    "FAST-AR": RecordCase("small", FAST, 250.0, 3.0, 0.8, displacement_sd=5e-6),
    "FAST-1C": RecordCase("small", (sine(10e-3, 1.0, 1), sine(5e-3, 2.0, 1), sine(2e-3, 5.0, 1)), 1000.0, 2.0),
    "FAST-100C": RecordCase("small", (sine(2e-3, 5.0, 100), sine(5e-3, 2.0, 100)), 1000.0, 2.0, force_step=1.0),
    "FAST-100HZ": RecordCase("small", FAST, 100.0, 2.0, displacement_sd=30e-6),
    "FAST-ADC": RecordCase("small", FAST, 1000.0, 1.0, force_step=1.0, displacement_step=10e-6),
    "FAST-25MM": RecordCase("small", (sine(25e-3, 0.5, 4), sine(25e-3, 0.25, 3)), 200.0, 2.0, 0.9),
    "SWEEP": RecordCase("small", (sweep(4e-3, 0.5, 4.0, 20.0), sweep(3e-3, 0.25, 5.0, 30.0, "exponential")), 500.0,
                        2.0, 0.8),
    "RANDOM": RecordCase("small", (random_motion(3e-3, 0.2, 3.0, 30.0),
                                   random_motion(0.03, 0.5, 5.0, 20.0, "velocity")), 250.0, 2.0),
    "RANDOM-AR": RecordCase("small", (random_motion(3e-3, 0.2, 3.0, 30.0),), 1000.0, 3.0, 0.97,
                            displacement_step=5e-6),
    "STOP-SMOOTH": RecordCase("small", SHORT, 500.0, 2.0, stop="smooth"),
    "STOP-ABRUPT": RecordCase("small", SHORT, 500.0, 2.0, stop="abrupt"),
    "REST": RecordCase("small", SHORT, 500.0, 2.0, start="rest", hold_s=1.0),
    "VELOCITY": RecordCase("small", SHORT, 500.0, 2.0, velocity_sd=1e-4),
}


# ----------------------------------------------------------------------------- data
def _resolve(case: str | RecordCase) -> tuple[str, RecordCase]:
    return (case, CASES[case]) if isinstance(case, str) else ("custom", case)


def draw_truth(seed, base_flow) -> dict:
    """α_V, p_R [Pa] and the four flow coefficients of one record, drawn from ``seed`` (see module doc)."""
    rng = np.random.default_rng(seed)
    alpha_v = math.exp(rng.uniform(*np.log(ALPHA_V_RANGE)))
    p_r = math.exp(rng.uniform(*np.log(P_R_RANGE)))
    flow = np.asarray(base_flow, dtype=float) * np.exp(rng.uniform(-FLOW_SPREAD, FLOW_SPREAD, 4))
    return {"alpha_V": alpha_v, "p_R_Pa": p_r, **dict(zip(FLOW_NAMES, flow.tolist(), strict=True))}


def build_input(m: Motion, cs: RecordCase, seed):
    """The input of one record and when its motion ends [s] (start, motion and stop of the case)."""
    if m.kind == "sine":
        inp = sine_at_speed(m.size, m.f_lo)
    elif m.kind.startswith("sweep-"):
        inp = sweep_input(m.size, m.f_lo, m.f_hi, m.length, law=m.kind.removeprefix("sweep-"))
    elif m.kind in ("random", "random-v"):
        key = "rms_displacement" if m.kind == "random" else "rms_velocity"
        inp = random_input(m.f_lo, m.f_hi, seed=seed, **{key: m.size})
    else:
        raise ValueError(f"unknown motion kind {m.kind!r}")
    t_end = m.seconds
    if cs.start == "rest":
        ramp = 1.0 / m.f_lo
        inp = start_from_rest(inp, cs.hold_s, ramp)
        t_end = cs.hold_s + ramp + m.seconds
    elif cs.start != "speed":
        raise ValueError(f"start must be 'speed' or 'rest', got {cs.start!r}")
    if cs.stop in ("smooth", "abrupt"):
        inp = stop_at(inp, t_end, STOP_TAPER_CYCLES / m.f_last if cs.stop == "smooth" else 0.0)
        t_end = t_end + inp.taper_s
    elif cs.stop != "none":
        raise ValueError(f"stop must be 'none', 'smooth' or 'abrupt', got {cs.stop!r}")
    return inp, t_end


def _simulate_case_record(args):
    k, m, cs, entropy = args
    damper, base_flow = DAMPERS[cs.damper]
    s_truth, s_input, s_noise = np.random.SeedSequence(entropy).spawn(3)
    truth = draw_truth(s_truth, base_flow)
    inp, t_end = build_input(m, cs, s_input)
    duration = t_end + (cs.hold_s if cs.stop != "none" else 0.0)
    t_start = (((k + 1) * 0.6180339887 + entropy[0] * 0.318) % 1.0) / cs.rate  # off the grid, per record
    sensors = Sensors(displacement_sd=cs.displacement_sd, displacement_step=cs.displacement_step,
                      force_sd=cs.force_sd, force_phi=cs.force_phi, force_step=cs.force_step,
                      velocity_channel=cs.velocity_sd is not None, velocity_sd=cs.velocity_sd or 0.0)
    rec = simulate_record(inp, duration, cs.rate, damper, [truth[n] for n in FLOW_NAMES], truth["alpha_V"],
                          truth["p_R_Pa"], seed=s_noise, sensors=sensors, t_start=t_start,
                          pre_roll_s=PRE_ROLL_CYCLES / m.f_lo if cs.start == "speed" else 0.0, rtol=RTOL)
    return f"r{k:02d}_{m.label}", rec, {**truth, "motion": asdict(m), "t_motion_end_s": t_end}


def make_case(case: str | RecordCase, folder, seed: int, *, workers: int = 1) -> Path:
    """Write one case's data set: ``damper.toml``, one CSV per motion, ``truth.json`` and the clean forces.

    Parameters
    ----------
    case : str or RecordCase
        A name of :data:`CASES` or a case.
    folder : str or Path
        Data-set folder (created).
    seed : int
        Seed of the truths, random inputs and noise (with the case's name: cases of one seed differ).
    workers : int
        Records simulated in parallel (processes).

    Returns
    -------
    Path
        The folder. ``truth.json``: ``{"case", "seed", "damper", "case_spec", "records": {name: {α_V, p_R,
        flow coefficients, motion, t_motion_end_s}}}``; :data:`CLEAN_FILE`: the true force per record [N].
    """
    name, cs = _resolve(case)
    key = zlib.crc32(repr(cs).encode() if name == "custom" else name.encode())
    tasks = [(k, m, cs, [int(seed), key, k]) for k, m in enumerate(cs.motions)]
    if workers > 1 and len(tasks) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(min(workers, len(tasks))) as ex:
            done = list(ex.map(_simulate_case_record, tasks))
    else:
        done = [_simulate_case_record(a) for a in tasks]
    damper, _ = DAMPERS[cs.damper]
    truth = {"case": name, "seed": int(seed), "damper": cs.damper, "case_spec": repr(cs),
             "records": {rn: tr for rn, _, tr in done}}
    root = write_records(folder, {rn: rec.measured for rn, rec, _ in done}, damper, f"record-coverage-{name}",
                         truth=truth)
    np.savez(root / CLEAN_FILE, **{rn: rec.force["total"] for rn, rec, _ in done})
    return root


# ----------------------------------------------------------------------------- identify and score
def run_identify(data: Path, out: Path, seed: int, extra: tuple[str, ...] = (), python: str | None = None) -> dict:
    """``bayesdamper identify`` on ``data``; returns its summary.json (read back if ``out`` has one)."""
    if (out / "summary.json").exists():
        return json.loads((out / "summary.json").read_text())
    cmd = [python or sys.executable, "-m", "bayesdamper.cli", "identify", str(data), "--out", str(out),
           "--seed", str(seed), "--no-figures", *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    if done.returncode != 0:
        raise RuntimeError(f"identify failed on {data} (status {done.returncode}): {done.stderr.strip()[-2000:]}")
    return json.loads((out / "summary.json").read_text())


def _read_force(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Time [s] and force [N] columns of a record CSV (by header name)."""
    header = path.read_text().split("\n", 1)[0].split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return data[:, header.index("time_s")], data[:, header.index("force_N")]


def window_samples(t: np.ndarray, window: dict, rate: float) -> np.ndarray:
    """Indices of the raw samples of a window: every ``decimation``-th sample in [t_start_s, t_end_s] (times
    matched to a quarter of a sample interval; the CSV holds the times the toolkit read)."""
    tol = 0.25 / rate
    idx = np.flatnonzero((t >= window["t_start_s"] - tol) & (t <= window["t_end_s"] + tol))
    return idx[:: max(1, int(window.get("decimation", 1)))]


def j_cost(model: np.ndarray, measured: np.ndarray) -> float:
    """Eq. (9): ||model - measured|| / ||measured||."""
    return float(np.linalg.norm(model - measured) / np.linalg.norm(measured))


def score(summary: dict, data: Path) -> list[dict]:
    """One row per window of ``summary["segments"]``, against ``data``'s truth.json, CSVs and clean forces.

    Row: ``id``, ``test``, ``kind``, ``converged``, ``J`` (the toolkit's), ``J_truth`` (eq. (9) of the clean
    force against the measured force over the window's raw samples), ``J_ratio`` = J / J_truth, ``n_samples``,
    and per parameter present in the entry: hit (bool), ``<p>_width`` = (hi - lo) / truth, ``<p>_z`` =
    (median - truth) / (half-width / 1.645).
    """
    data = Path(data)
    truth = json.loads((data / "truth.json").read_text())["records"]
    clean = np.load(data / CLEAN_FILE)
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    rows = []
    for e in summary["segments"]:
        rec = e["test"]
        if rec not in cache:
            cache[rec] = _read_force(data / f"{rec}.csv")
        t, f = cache[rec]
        rate = 1.0 / float(np.median(np.diff(t)))
        sel = window_samples(t, e["window"], rate)
        j_truth = j_cost(clean[rec][sel], f[sel])
        row = {"id": e["id"], "test": rec, "kind": e.get("kind"), "converged": bool(e.get("converged")),
               "J": float(e["J"]), "J_truth": j_truth, "J_ratio": float(e["J"]) / j_truth,
               "n_samples": int(sel.size)}
        for p in PARAMS:
            est = (e.get("flow") or {}).get(SUMMARY_FLOW[p]) if p in FLOW_NAMES else e.get(p)
            if not est:
                continue
            lo, hi, med, tr = est["lo"], est["hi"], est["median"], truth[rec][p]
            row[p] = bool(lo <= tr <= hi)
            row[p + "_width"] = (hi - lo) / tr
            row[p + "_z"] = (med - tr) / max(0.5 * (hi - lo) / Z90, 1e-300)
        rows.append(row)
    return rows


def table(rows: list[dict]) -> dict:
    """Per parameter: n, hits, coverage, median relative 90 % width; converged share; J_ratio quantiles."""
    out = {}
    for p in PARAMS:
        sel = [r for r in rows if p in r]
        if sel:
            out[p] = {"n": len(sel), "hits": int(sum(r[p] for r in sel)),
                      "coverage": float(np.mean([r[p] for r in sel])),
                      "median_width": float(np.median([r[p + "_width"] for r in sel]))}
    if rows:
        ratio = np.array([r["J_ratio"] for r in rows])
        out["converged"] = float(np.mean([r["converged"] for r in rows]))
        out["J_ratio"] = {**{f"q{round(100 * q):02d}": float(np.quantile(ratio, q)) for q in J_QUANTILES},
                          "max": float(ratio.max())}
    return out


def tables(rows: list[dict]) -> dict:
    """:func:`table` per case (rows' ``case`` key) and over all rows (``"all"``)."""
    cases = sorted({r.get("case", "custom") for r in rows})
    return {**{c: table([r for r in rows if r.get("case", "custom") == c]) for c in cases}, "all": table(rows)}


def format_table(tab: dict) -> str:
    """Text lines of a :func:`table`."""
    lines = []
    for p in PARAMS:
        if p in tab:
            v = tab[p]
            lines.append(f"   {p:8s} {v['hits']:3d}/{v['n']:3d} = {v['coverage']:.2f}  "
                         f"width {100 * v['median_width']:.2f} %")
    if "J_ratio" in tab:
        q = tab["J_ratio"]
        lines.append(f"   converged {tab['converged']:.2f}; J_fit / J_truth " +
                     ", ".join(f"{k} {v:.3f}" for k, v in q.items()))
    return "\n".join(lines)


def run_cases(names, seeds, out: Path, extra: tuple[str, ...] = (), python: str | None = None,
              workers: int = 2, verbose: bool = True) -> dict:
    """Make, identify and score every case × seed; returns ``{"rows": [...], "tables": tables(rows)}``.

    Folders: ``out/<case>_<seed>/data`` (the data set) and ``out/<case>_<seed>/out`` (identify's output, read
    back when present: a rerun only scores).
    """
    rows = []
    for name in names:
        for seed in seeds:
            t0 = time.perf_counter()
            base = Path(out) / f"{name}_{seed}"
            data = base / "data"
            if not (data / "truth.json").exists():
                make_case(name, data, seed, workers=workers)
            summ = run_identify(data, base / "out", seed, tuple(extra), python)
            case_rows = score(summ, data)
            for r in case_rows:
                r["case"], r["seed"] = name, seed
            rows += case_rows
            if verbose:
                print(f"== {name} seed {seed} ({time.perf_counter() - t0:.0f} s, {len(case_rows)} windows)")
                print(format_table(table(case_rows)))
                sys.stdout.flush()
    return {"rows": rows, "tables": tables(rows)}


# ----------------------------------------------------------------------------- data sets for later tests
#: Gas charge of the small damper's accumulator: a 14 mm rod (A_rod = π 7e-3^2 m^2) and 20 cm^3 of nitrogen,
#: compressed adiabatically (n = 1.4) at test frequencies of 0.5-2 Hz.
ROD_AREA = math.pi * 7e-3**2  # [m^2]
GAS_VOLUME = 2.0e-5  # [m^3]
POLYTROPIC = 1.4


def make_conditions(folder, *, charges=(2.5e5, 5.0e5, 1.0e6), seed: int = 0, rate: float = 500.0,
                    motions=((10e-3, 0.5, 4), (8e-3, 1.0, 5), (4e-3, 2.0, 8))) -> list[Path]:
    """One damper at several charge pressures: one data set per charge, with a ``[condition]`` table.

    Truth (the same in every folder unless said): the small damper (``SMALL``), flow ``SMALL_FLOW``, α_V = 60;
    p_R = the charge pressure (the accumulator's charge is the pressurisation level that eq. (6) calls p_R);
    a gas spring on the rod (:class:`independent_records.GasCharge`, linearised: F_gas = p_c A_rod + k y, A_rod
    = :data:`ROD_AREA`, V_g = :data:`GAS_VOLUME`, n = 1.4: 38.5, 77 and 154 N of offset at 0.25, 0.5 and 1 MPa,
    k = 415-1660 N/m); a rig effect the same at all charges: Coulomb friction 30 N, tanh(v / 1 mm/s). Records:
    sines (amplitude [m], frequency [Hz], cycles) of ``motions`` starting at speed in steady state (two periods
    of pre-roll), ``rate`` [Hz], 2 N white force noise, 5 µm displacement noise.

    Returns
    -------
    list of Path
        ``folder/charge_<p>kPa`` per charge; each with ``damper.toml`` (``[condition] charge_pressure_Pa``),
        CSVs and ``truth.json`` (every number above, per folder).
    """
    alpha_v, coulomb, v_eps = 60.0, 30.0, 1e-3
    sensors = Sensors(force_sd=2.0, displacement_sd=5e-6)
    out = []
    for i, p_c in enumerate(charges):
        gas = GasCharge(float(p_c), ROD_AREA, GAS_VOLUME, POLYTROPIC)
        records = {}
        for k, (a, f, cyc) in enumerate(motions):
            rec = simulate_record(sine_at_speed(a, f), cyc / f, rate, SMALL, SMALL_FLOW, alpha_v, float(p_c),
                                  seed=[seed, i, k], sensors=sensors, t_start=(0.37 + 0.11 * k) / rate,
                                  pre_roll_s=PRE_ROLL_CYCLES / f, coulomb=coulomb, v_eps=v_eps, gas=gas, rtol=RTOL)
            records[f"sine_{f:g}Hz_{a * 1e3:g}mm".replace(".", "p")] = rec.measured
        truth = {"generator": "tests/record_coverage.py make_conditions", "seed": seed, "model": "eq7",
                 "alpha_V": alpha_v, "p_R_Pa": float(p_c), **dict(zip(FLOW_NAMES, SMALL_FLOW, strict=True)),
                 "effects": {"gas": {"charge_pressure_Pa": float(p_c), "rod_area_m2": ROD_AREA,
                                     "gas_volume_m3": GAS_VOLUME, "polytropic": POLYTROPIC,
                                     "offset_N": gas.preload, "rate_N_per_m": gas.rate},
                             "friction": {"coulomb_N": coulomb, "v_eps_m_s": v_eps}},
                 "sensors": asdict(sensors), "rate_Hz": rate}
        name = f"charge_{p_c / 1e3:g}kPa".replace(".", "p")
        out.append(write_records(Path(folder) / name, records, SMALL, "gas-charged-small",
                                 condition={"charge_pressure_Pa": float(p_c)}, truth=truth))
    return out


#: The MR-like records: (amplitude [m], frequency [Hz], cycles, rate [Hz], mean [m], starts from rest).
MR_RECORDS = ((25e-3, 0.25, 3, 200.0, 0.0, True), (12e-3, 0.5, 5, 200.0, 5e-3, False),
              (8e-3, 1.0, 8, 500.0, 5e-3, True), (4e-3, 2.0, 10, 500.0, 5e-3, False),
              (2e-3, 5.0, 20, 1000.0, 5e-3, False))


def make_mr_habits(folder, *, seed: int = 0, records=MR_RECORDS) -> Path:
    """An MR-like data set with the habits of real records (like ``data/lab-MR``).

    Truth: the small damper (``SMALL``), flow ``SMALL_FLOW``, α_V = 40, p_R = 0.2 MPa; dry friction (Bingham
    yield with no post-yield term) 150 N, tanh(v / 1 mm/s): friction-dominated, the fluid force reaching it only
    near the peak speeds (38-63 mm/s: 120-210 N); the load cell not zeroed: +140 N on the force channel; force
    noise 1.5 N white, force ADC step 3 N, displacement ADC step 5 µm. Records (``records``: amplitude [m],
    frequency [Hz], cycles, rate [Hz], mean displacement [m], start from rest): sines 0.25-5 Hz, 2-25 mm,
    200 Hz-1 kHz; a start from rest holds 1 s and ramps in over one period, the others start at speed in steady
    state (two periods of pre-roll).

    Returns
    -------
    Path
        ``folder`` with ``damper.toml``, CSVs and ``truth.json``.
    """
    alpha_v, p_r, f_yield, v_eps = 40.0, 2.0e5, 150.0, 1e-3
    sensors = Sensors(force_sd=1.5, force_step=3.0, force_offset=140.0, displacement_step=5e-6)
    out, specs = {}, []
    for k, (a, f, cyc, rate, mean, from_rest) in enumerate(records):
        if from_rest:
            hold, ramp = 1.0, 1.0 / f
            inp = start_from_rest(sine_input(a, f, offset=mean), hold, ramp, rest=mean)
            kw = {"duration": hold + ramp + cyc / f}
        else:
            inp = sine_at_speed(a, f, offset=mean)
            kw = {"duration": cyc / f, "pre_roll_s": PRE_ROLL_CYCLES / f}
        rec = simulate_record(inp, rate=rate, damper=SMALL, flow=SMALL_FLOW, alpha_v=alpha_v, p_r=p_r,
                              seed=[seed, k], sensors=sensors, t_start=0.0, coulomb=f_yield, v_eps=v_eps, rtol=RTOL,
                              **kw)
        name = f"mr_{f:g}Hz_{a * 1e3:g}mm".replace(".", "p")
        out[name] = rec.measured
        specs.append({"record": name, "amplitude_m": a, "frequency_Hz": f, "cycles": cyc, "rate_Hz": rate,
                      "mean_m": mean, "start": "rest" if from_rest else "speed"})
    truth = {"generator": "tests/record_coverage.py make_mr_habits", "seed": seed, "model": "eq7",
             "alpha_V": alpha_v, "p_R_Pa": p_r, **dict(zip(FLOW_NAMES, SMALL_FLOW, strict=True)),
             "effects": {"friction": {"coulomb_N": f_yield, "v_eps_m_s": v_eps}, "offset": {"offset_N": 140.0}},
             "sensors": asdict(sensors), "records": specs}
    return write_records(folder, out, SMALL, "mr-like", truth=truth)


def make_triangle_artefacts(folder, *, seed: int = 0, speeds=SPEEDS, rate: float = 250.0) -> Path:
    """Rig-A's triangular protocol on a two-state damper, with load-cell artefacts.

    Truth: the two-state model eq. (1) without accumulator (:func:`independent.simulate_two_state`; misspecified
    for eq. (7)), rig-A's constants (``RIG_A``), flow ``PAPER_FLOW``, α_V = 40 at the charge, charge pressure
    0.6 MPa; rig-A's protocol (1 s at rest, then a 5 mm triangle for 1.25 cycles, first step off the sample grid)
    at ``speeds`` [m/s], ``rate`` [Hz]; force channel: +80 N offset (load cell not zeroed), 40 N of 50 Hz mains
    hum (phase drawn per record, in truth.json), 10 N white noise. No pseudo-true α_V, p_R are computed here
    (``transient_coverage.pseudo_true`` does that for clean two-state records).

    Returns
    -------
    Path
        ``folder`` with ``damper.toml``, CSVs and ``truth.json``.
    """
    alpha_v, p_charge = 40.0, 6.0e5
    rng = np.random.default_rng([seed, 50])
    out, specs = {}, []
    for k, v in enumerate(speeds):
        t_first = REST + (((k + 1) * 0.6180339887 + seed * 0.318) % 1.0) / rate
        hum_phase = float(rng.uniform(0.0, 2.0 * np.pi))
        sensors = Sensors(force_sd=10.0, force_offset=80.0, hum_amplitude=40.0, hum_frequency=50.0,
                          hum_phase=hum_phase)
        inp = triangle_input(v, AMPLITUDE, 0.0, t_first, cycles=1.25)
        rec = simulate_record(inp, t_first + 5 * AMPLITUDE / v + 0.05, rate, RIG_A, PAPER_FLOW, alpha_v, p_charge,
                              seed=[seed, k, 50], sensors=sensors, model="two-state")
        name = f"tri_{v * 1e3:.2f}mm_s".replace(".", "p")
        out[name] = rec.measured
        specs.append({"record": name, "speed_m_s": v, "t_first_step_s": t_first, "hum_phase_rad": hum_phase})
    truth = {"generator": "tests/record_coverage.py make_triangle_artefacts", "seed": seed, "model": "two-state",
             "alpha_V": alpha_v, "charge_pressure_Pa": p_charge, **dict(zip(FLOW_NAMES, PAPER_FLOW, strict=True)),
             "effects": {"offset": {"offset_N": 80.0}, "mains_hum": {"amplitude_N": 40.0, "frequency_Hz": 50.0}},
             "force_noise_sd_N": 10.0, "rate_Hz": rate, "amplitude_m": AMPLITUDE, "records": specs}
    return write_records(folder, out, RIG_A, "two-state-artefacts", truth=truth)


# ----------------------------------------------------------------------------- command line
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+", choices=sorted(CASES))
    ap.add_argument("--out", type=Path, default=Path("/tmp/record_coverage"))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--json", type=Path, default=None, help="write the rows and tables to this JSON file")
    ap.add_argument("--python", default=None, help="interpreter running bayesdamper (default: this one)")
    ap.add_argument("--extra", default="", help="extra identify options, space separated")
    ap.add_argument("--workers", type=int, default=2, help="records simulated in parallel")
    a = ap.parse_args(argv)
    res = run_cases(a.cases, [int(s) for s in a.seeds.split(",")], a.out, tuple(a.extra.split()), a.python,
                    a.workers)
    for name, tab in res["tables"].items():
        print(f"== {name}" + (" (every case and seed)" if name == "all" else " (every seed)"))
        print(format_table(tab))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
