"""The jobs' worker processes each run one BLAS thread (bayesdamper.run.threads)."""

from __future__ import annotations

import inspect
import multiprocessing as mp

import numpy as np  # noqa: F401  (loads numpy's OpenBLAS, whose pool is limited)
import pytest
from threadpoolctl import threadpool_info

from bayesdamper.run.threads import one_blas_thread


def _blas_threads(_=None) -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="the jobs fork their workers")
def test_one_blas_thread_in_the_process_and_in_its_forked_workers():
    assert _blas_threads(), "no BLAS pool found"
    with one_blas_thread():
        assert set(_blas_threads()) == {1}
        with mp.get_context("fork").Pool(2) as pool:
            assert all(set(t) == {1} for t in pool.map(_blas_threads, range(2)))


def test_the_cli_and_the_diagnosis_run_with_one_blas_thread(monkeypatch, tmp_path):
    """Both entry points enter the limit: a command that fails inside it still saw one thread."""
    from bayesdamper import cli
    from bayesdamper.core.errors import SettingsError
    from bayesdamper.run import diagnose

    seen = []

    def fake_plan(*args, **kwargs):
        seen.append(set(_blas_threads()))
        raise SettingsError("stop here")

    monkeypatch.setattr("bayesdamper.run.plan.plan_dataset", fake_plan)
    with pytest.raises(SettingsError):
        diagnose.run_diagnosis(str(tmp_path), str(tmp_path / "out"))
    monkeypatch.setattr("bayesdamper.run.check.run_check", lambda *a, **k: seen.append(set(_blas_threads())))
    assert cli.main(["check", str(tmp_path)]) == 0
    assert seen == [{1}, {1}]
    assert "seed" in inspect.signature(diagnose.run_diagnosis).parameters  # the decorator keeps the signature
