"""Runs that survive: resume after a kill, untouched results on bad input, settings guard, Dask equality.

Everything runs on a tiny synthetic data set (100 Hz, three speeds), two transients, a short step
budget and no figures, so the whole file takes about a minute (the Dask test, about 20 s, is skipped
when Dask is not installed).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bayesdamper import cli
from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.params import DynamicParameters
from bayesdamper.io.synthetic import write_dataset
from bayesdamper.run.identify import run_identify
from bayesdamper.run.outfolder import RUN_FILE, settings_fingerprint

ROOT = Path(__file__).resolve().parents[1]
#: The transients every run here samples (one initial step, one reversal).
ONLY = "tri_1p00mm_s_s0,tri_1p50mm_s_s1"
#: Step budget per ensemble: far from converged, but enough to exercise everything.
MAX_STEPS = 600
#: Seconds to wait for a subprocess run before failing.
TIMEOUT_S = 300


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ops")
    return write_dataset(root / "sim", [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(1 / 0.03, 3.0e5),
                         sample_rate=100.0, noise_n=20.0, seed=1)


@pytest.fixture(scope="module")
def reference(data, tmp_path_factory) -> tuple[Path, dict]:
    """An uninterrupted run (in this process) and its summary as written."""
    out = tmp_path_factory.mktemp("ops_ref") / "out"
    run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS, workers=1, figures=False)
    return out, json.loads((out / "summary.json").read_text())


def comparable(summary: dict) -> dict:
    """The summary without wall times, NaN made comparable."""
    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items() if k not in ("wall_s", "wall_time_s")}
        if isinstance(x, list):
            return [clean(v) for v in x]
        if isinstance(x, float) and math.isnan(x):
            return "nan"
        return x

    return clean(json.loads(json.dumps(summary)))


def tree_state(folder: Path) -> dict[str, tuple[str, int]]:
    """``{relative path: (sha256, mtime_ns)}`` of every file under ``folder``."""
    return {p.relative_to(folder).as_posix(): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def identify_cmd(data: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "bayesdamper", "identify", str(data), "--out", str(out), "--only", ONLY,
            "--max-steps", str(MAX_STEPS), "--workers", "1", "--no-figures", *extra]


def test_killed_run_resumes_without_touching_finished_transients(data, reference, tmp_path):
    out = tmp_path / "out"
    post = out / "posteriors"
    proc = subprocess.Popen(identify_cmd(data, out), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + TIMEOUT_S
    try:
        while not (post.is_dir() and any(post.glob("*.nc"))):
            assert proc.poll() is None, f"run ended before it could be killed: {proc.communicate()}"
            assert time.monotonic() < deadline, "no posterior file appeared"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
        proc.stdout.close()
        proc.stderr.close()
    finished = tree_state(post)
    assert list(finished) == ["tri_1p00mm_s_s0.nc"]  # the second was mid-sampling: no file
    assert not (out / "summary.json").exists()
    assert json.loads((out / RUN_FILE).read_text())["status"] == "running"

    again = subprocess.run(identify_cmd(data, out), cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert again.returncode == 0, again.stderr
    assert f"resumed 1 finished window(s) from {post}" in again.stderr
    # not a terminal: one summary line per phase, with counts and wall time, and no bar
    phases = [ln for ln in again.stderr.splitlines() if ": " in ln and " in " in ln and ln.endswith(("s", ")"))]
    assert any(ln.startswith("load, classify, windows, stage 1: 1 data set in ") for ln in phases), again.stderr
    assert any(re.fullmatch(r"posteriors \(\w+\): 1/1 window in [\d.]+ s \([01] converged, 1 resumed\)", ln)
               for ln in phases), again.stderr
    assert "\r" not in again.stderr and "it/s" not in again.stderr
    after = tree_state(post)
    assert after["tri_1p00mm_s_s0.nc"] == finished["tri_1p00mm_s_s0.nc"]  # byte-for-byte, not rewritten
    assert set(after) == {"tri_1p00mm_s_s0.nc", "tri_1p50mm_s_s1.nc"}
    assert comparable(json.loads((out / "summary.json").read_text())) == comparable(reference[1])
    run = json.loads((out / RUN_FILE).read_text())
    assert run["status"] == "complete"
    assert run["resumed"] == ["tri_1p00mm_s_s0"] and run["computed"] == ["tri_1p50mm_s_s1"]
    assert run["fingerprint"] == settings_fingerprint(run["fingerprint_basis"])
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


def test_finished_run_is_not_recomputed_and_leftover_temporaries_go(data, reference, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(reference[0], out)
    (out / "posteriors" / ".tri_1p50mm_s_s1.nc.tmp4242").write_bytes(b"half a file")  # as a kill leaves it
    before = tree_state(out / "posteriors")
    summary = run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS, workers=1, figures=False)
    after = tree_state(out / "posteriors")
    assert after == {k: v for k, v in before.items() if ".tmp" not in k}
    assert comparable(summary) == comparable(reference[1])
    assert json.loads((out / RUN_FILE).read_text())["computed"] == []


def _bad_copy(data: Path, tmp_path: Path) -> Path:
    bad = tmp_path / "bad"
    shutil.copytree(data, bad)
    (bad / "tri_1p00mm_s.csv").write_text("time_s,displacement_m,force_N\n0,0,nan\n")
    return bad


def test_bad_input_leaves_existing_results_byte_for_byte(data, reference, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(reference[0], out)
    before = tree_state(out)
    options = ["--out", str(out), "--max-steps", str(MAX_STEPS), "--no-figures"]
    bad_runs = [
        ([_bad_copy(data, tmp_path)], []),                # a malformed CSV
        ([tmp_path / "missing"], []),                     # no such folder
        ([data], ["--noise-model", "pink"]),              # impossible settings
        ([data], ["--p-r-prior", "5,1"]),
        ([data], ["--only", "nope_s0"]),                  # unknown transient
        ([data, data], []),                               # the same data set twice: name clash
        ([data], ["--seed", "7"]),                        # results of other settings, no --force
    ]
    for dirs, extra in bad_runs:
        only = [] if "--only" in extra else ["--only", ONLY]
        assert cli.main(["identify", *map(str, dirs), *options, *only, *extra]) == 2, (dirs, extra)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("bayesdamper: error: "), err
    assert tree_state(out) == before


def test_other_settings_need_force(data, reference, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(reference[0], out)
    before = tree_state(out)
    with pytest.raises(SettingsError) as info:
        run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS + 1, seed=3, figures=False)
    msg = str(info.value)
    assert msg.startswith(f"{out}: holds results of different settings (") and "--force" in msg
    assert "seed 0 -> 3" in msg and "settings.sampler.max_steps 600 -> 601" in msg and "\n" not in msg
    assert tree_state(out) == before

    summary = run_identify(str(data), str(out), only="tri_1p00mm_s_s0", max_steps=200, seed=3, workers=1,
                           figures=False, force=True)
    assert summary["seed"] == 3 and [e["id"] for e in summary["segments"]] == ["tri_1p00mm_s_s0"]
    assert sorted(p.name for p in (out / "posteriors").iterdir()) == ["tri_1p00mm_s_s0.nc"]  # old ones cleared
    run = json.loads((out / RUN_FILE).read_text())
    assert run["fingerprint_basis"]["seed"] == 3 and run["computed"] == ["tri_1p00mm_s_s0"]


def test_results_of_unknown_settings_are_refused(data, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"keep": true}\n')
    with pytest.raises(SettingsError, match="summary.json records no readable settings"):
        run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS, figures=False)
    assert (out / "summary.json").read_text() == '{"keep": true}\n'
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]


def test_bad_data_set_among_several_writes_nothing(data, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(DataError):
        run_identify([str(data), str(_bad_copy(data, tmp_path))], str(out), only=ONLY, max_steps=MAX_STEPS)
    assert not out.exists()


def test_several_data_sets_go_to_their_own_folders(data, tmp_path):
    other = write_dataset(tmp_path / "rig-B", [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(50.0, 2.0e5),
                          sample_rate=100.0, noise_n=20.0, seed=2)
    out = tmp_path / "out"
    summaries = run_identify([str(data), str(other)], str(out), only="tri_1p50mm_s_s1", max_steps=200,
                             workers=1, figures=False)
    assert [s["dataset"] for s in summaries] == ["sim", "rig-B"]
    for name in ("sim", "rig-B"):
        assert (out / name / "summary.json").is_file() and (out / name / RUN_FILE).is_file()
        assert [p.name for p in (out / name / "posteriors").iterdir()] == ["tri_1p50mm_s_s1.nc"]
    assert not (out / "summary.json").exists()


def test_missing_dask_is_a_one_line_error_before_any_write(data, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # makes the import fail
    out = tmp_path / "out"
    with pytest.raises(SettingsError, match=r"--scheduler: dask.distributed is not installed .*bayesdamper\["):
        run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS, scheduler="tcp://127.0.0.1:8786")
    assert not out.exists()


def test_dask_cluster_gives_the_local_results(data, reference, tmp_path):
    dd = pytest.importorskip("dask.distributed")
    out = tmp_path / "out"
    with dd.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        summary = run_identify(str(data), str(out), only=ONLY, max_steps=MAX_STEPS, figures=False,
                               scheduler=cluster.scheduler_address)
    assert comparable(summary) == comparable(reference[1])
    assert sorted(p.name for p in (out / "posteriors").iterdir()) == ["tri_1p00mm_s_s0.nc", "tri_1p50mm_s_s1.nc"]
    assert json.loads((out / RUN_FILE).read_text())["scheduler"] == cluster.scheduler_address
