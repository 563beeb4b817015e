"""The command line: good runs exit 0; every bad input exits non-zero with one clear line, no traceback."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
RIG_A = ROOT / "data" / "rig-A"


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "bayesdamper", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def assert_clean_error(proc, *needles):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]


def test_check_on_rig_a_without_fit():
    proc = run("check", RIG_A, "--no-fit")
    assert proc.returncode == 0, proc.stderr
    assert "33 transient(s)" in proc.stdout
    assert "C_L12" in proc.stdout and "C_Q21" in proc.stdout


@pytest.fixture()
def rig_copy(tmp_path):
    dst = tmp_path / "rig"
    shutil.copytree(RIG_A, dst)
    for p in dst.iterdir():
        p.chmod(0o644)
    return dst


def test_missing_folder(tmp_path):
    assert_clean_error(run("check", tmp_path / "nope"), "nope")


def test_missing_toml(rig_copy):
    (rig_copy / "damper.toml").unlink()
    assert_clean_error(run("check", rig_copy), "damper.toml")


def test_toml_syntax_error(rig_copy):
    (rig_copy / "damper.toml").write_text("[damper\npiston_area_m2 = 1\n")
    assert_clean_error(run("check", rig_copy), "damper.toml")


def test_missing_key(rig_copy):
    txt = (rig_copy / "damper.toml").read_text().replace("piston_area_m2 = 0.0042\n", "")
    (rig_copy / "damper.toml").write_text(txt)
    assert_clean_error(run("check", rig_copy), "piston_area_m2")


def test_nan_in_csv(rig_copy):
    f = rig_copy / "tri_1p00mm_s.csv"
    lines = f.read_text().splitlines()
    lines[100] = "0.396,nan,12.0"
    f.write_text("\n".join(lines) + "\n")
    assert_clean_error(run("check", rig_copy), "tri_1p00mm_s.csv")


def test_millimetres(rig_copy):
    f = rig_copy / "tri_1p00mm_s.csv"
    lines = f.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        t, y, F = ln.split(",")
        out.append(f"{t},{float(y) * 1e3},{F}")
    f.write_text("\n".join(out) + "\n")
    assert_clean_error(run("check", rig_copy), "tri_1p00mm_s.csv", "millimetres")


def test_binary_junk(rig_copy):
    (rig_copy / "tri_1p00mm_s.csv").write_bytes(bytes(range(256)) * 20)
    assert_clean_error(run("check", rig_copy), "tri_1p00mm_s.csv")


def test_too_short(rig_copy):
    f = rig_copy / "tri_1p00mm_s.csv"  # 1.2 s: 0.97 s at rest and 0.2 s of the first ramp, no velocity step
    f.write_text("\n".join(f.read_text().splitlines()[:300]) + "\n")
    assert_clean_error(run("check", rig_copy), "tri_1p00mm_s.csv")


def test_record_that_ends_within_tmax_of_a_step(rig_copy):
    """7.5 s of the 1 mm/s test: the start from rest, the reversal at 6 s and 1.5 s of the next ramp. The reversal's
    window ends with the record; the record has no third transient."""
    f = rig_copy / "tri_1p00mm_s.csv"
    f.write_text("\n".join(f.read_text().splitlines()[:1876]) + "\n")
    proc = run("check", rig_copy, "--no-fit")
    assert proc.returncode == 0, proc.stderr
    assert "32 transient(s)" in proc.stdout
    rows = [ln.split() for ln in proc.stdout.splitlines() if ln.startswith("tri_1p00mm_s ")]
    assert [(r[1], r[2]) for r in rows] == [("0", "initial"), ("1", "reversal")]
    window = [float(r[6]) for r in rows]  # the "window [s]" column
    # a window ends at the last sample within it, its step (a knot) within a sample of the first: 2 samples
    assert window[0] == pytest.approx(3.0, abs=2 / 250) and window[1] == pytest.approx(1.5, abs=2 / 250)


def test_bad_settings_are_one_line_errors(rig_copy, tmp_path):
    assert_clean_error(run("identify", rig_copy, "--out", tmp_path / "o", "--noise-model", "pink"), "pink")
    assert_clean_error(run("identify", rig_copy, "--out", tmp_path / "o", "--p-r-prior", "5,1"),
                       "--p-r-prior")
    assert not (tmp_path / "o").exists()


def test_bad_input_leaves_existing_results_untouched(rig_copy, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"keep": true}\n')
    (rig_copy / "damper.toml").write_text("garbage = [\n")
    proc = run("identify", rig_copy, "--out", out)
    assert proc.returncode != 0
    assert (out / "summary.json").read_text() == '{"keep": true}\n'
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]


def test_simulate_then_identify_one_transient(tmp_path):
    data = tmp_path / "sim"
    proc = run("simulate", data, "--velocities", "0.5,1.0,1.5", "--seed", "3", "--noise-n", "20")
    assert proc.returncode == 0, proc.stderr
    truth = json.loads((data / "truth.json").read_text())
    assert truth["seed"] == 3 and truth["model"] == "eq7"
    assert_clean_error(run("simulate", data), "exists")  # no silent overwrite
    out = tmp_path / "res"
    proc = run("identify", data, "--out", out, "--only", "tri_1p00mm_s_s0", "--workers", "1", "--no-figures")
    assert proc.returncode == 0, proc.stderr
    assert "wall time" in proc.stdout
    s = json.loads((out / "summary.json").read_text())
    assert set(s) >= {"dataset", "credible_mass", "static", "segments", "drift"}
    assert set(s["static"]) == {"CL12", "CQ12", "CL21", "CQ21"}
    (seg,) = s["segments"]
    assert set(seg) >= {"id", "test", "kind", "direction", "velocity_m_s", "t_start_s", "alpha_V", "p_R_Pa",
                        "ls", "J", "rhat_max", "ess_bulk_min", "converged"}
    assert seg["kind"] == "initial" and seg["direction"] == 1
    assert seg["alpha_V"]["lo"] <= truth["alpha_V"] <= seg["alpha_V"]["hi"]
    assert (out / "posteriors" / "tri_1p00mm_s_s0.nc").exists()


def test_fast_test_whose_ramps_are_shorter_than_tmax(tmp_path):
    """4 mm/s over the simulator's 5 mm amplitude: 1.25 s out from rest and 2.5 s between reversals, both under the
    default T_max of 3 s. Every window ends with its ramp, and the start's posterior holds the truth."""
    data = tmp_path / "fast"
    proc = run("simulate", data, "--velocities", "1.0,2.5,4.0", "--seed", "5", "--noise-n", "20")
    assert proc.returncode == 0, proc.stderr
    truth = json.loads((data / "truth.json").read_text())
    proc = run("check", data, "--no-fit")
    assert proc.returncode == 0, proc.stderr
    assert "9 transient(s)" in proc.stdout
    out = tmp_path / "res"
    proc = run("identify", data, "--out", out, "--only", "tri_4p00mm_s_s0,tri_4p00mm_s_s1,tri_1p00mm_s_s1",
               "--workers", "1", "--no-figures")
    assert proc.returncode == 0, proc.stderr
    segs = {s["id"]: s for s in json.loads((out / "summary.json").read_text())["segments"]}
    length = {k: s["window"]["t_end_s"] - s["t_start_s"] for k, s in segs.items()}
    rate = 250.0  # the simulator's default sample rate [Hz]: a window ends within a sample of its ramp's end
    assert length["tri_4p00mm_s_s0"] == pytest.approx(1.25, abs=2 / rate)
    assert length["tri_4p00mm_s_s1"] == pytest.approx(2.5, abs=2 / rate)
    assert length["tri_1p00mm_s_s1"] == pytest.approx(3.0, abs=1 / rate)  # a 10 s ramp: T_max
    start = segs["tri_4p00mm_s_s0"]
    assert start["kind"] == "initial" and start["converged"]
    assert start["alpha_V"]["lo"] <= truth["alpha_V"] <= start["alpha_V"]["hi"]


# ----------------------------------------------------------------------------- the command line as a user meets it


def test_help_describes_the_tool_not_the_source_file():
    proc = run("--help")
    assert proc.returncode == 0, proc.stderr
    assert "Identify liquid-damper models" in proc.stdout
    assert "No logic lives here" not in proc.stdout
    for command in ("check", "simulate", "identify", "report", "diagnose", "predict"):
        assert command in proc.stdout
    assert "examples:" in proc.stdout


def test_version():
    from bayesdamper import __version__

    proc = run("--version")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"bayesdamper {__version__}"


def _options():
    import argparse

    from bayesdamper.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, command in sub.choices.items():
        command.format_help()  # builds the help texts that are made only when shown
        for action in command._actions:
            if action.option_strings and not isinstance(action, argparse._HelpAction):
                yield name, action


def test_every_option_has_help_with_its_default_and_unit():
    options = list(_options())
    assert len(options) > 30
    for command, action in options:
        text = action.help or ""
        where = f"{command} {action.option_strings[0]}"
        assert text, f"{where}: no help"
        assert "default" in text or "required" in text, f"{where}: no default in {text!r}"
        if action.type is not None and action.type not in (str,) and action.nargs is None \
                and "prior" not in action.dest and action.dest != "velocities":
            assert "[" in text and "]" in text, f"{where}: numeric option without a unit: {text!r}"


def test_defaults_in_help_are_the_defaults():
    # the stated defaults are computed from the values the code uses, so they cannot drift apart
    from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS
    from bayesdamper.inference.sampling import SamplerSettings

    helps = {(c, a.dest): a.help for c, a in _options()}
    assert f"default: {SamplerSettings().max_steps})" in helps[("identify", "max_steps")]
    assert "{:g},{:g}".format(*ALPHA_V_BOUNDS) in helps[("identify", "alpha_v_prior")]
    assert "{:g},{:g}".format(*P_R_BOUNDS) in helps[("report", "p_r_prior")]


@pytest.mark.parametrize("args, needle", [
    ((), "COMMAND"),
    (("identify",), "--out"),
    (("frobnicate",), "frobnicate"),
    (("check", "somewhere", "--tmax", "-1"), "--tmax"),
])
def test_usage_errors_are_one_line_with_exit_status_2(args, needle):
    proc = run(*args)
    assert proc.returncode == 2
    assert_clean_error(proc, needle, "--help")


def _saturating_data_set(folder: Path) -> Path:
    """Triangular tests of a damper whose static force saturates with speed (F = F_max tanh(v / v_0)), with
    a first-order force lag after each velocity step: written here with numpy alone, not by bayesdamper."""
    folder.mkdir()
    (folder / "damper.toml").write_text((RIG_A / "damper.toml").read_text().replace('"rig-A"', '"saturating"'))
    rng = np.random.default_rng(11)
    f_max, v_0, tau, amp, rest, rate = 8000.0, 0.6e-3, 0.15, 3.0e-3, 1.0, 200.0
    for v in (0.5e-3, 0.8e-3, 1.1e-3, 1.4e-3):
        quarter = amp / v
        t = np.arange(0.0, rest + 5 * quarter, 1 / rate)
        phase = np.clip(t - rest, 0, None) / quarter  # 0..5 quarters: 0 -> A -> -A -> A
        tri = np.where(phase < 1, phase, np.where(phase < 3, 2 - phase, phase - 4)) * amp
        vel = np.gradient(tri, t)
        target = f_max * np.tanh(np.round(vel / v, 6) * v / v_0)
        force = np.empty_like(t)
        force[0] = 0.0
        for k in range(1, t.size):  # exact first-order lag towards the piecewise-constant target
            force[k] = target[k] + (force[k - 1] - target[k]) * np.exp(-(t[k] - t[k - 1]) / tau)
        rows = np.column_stack([t, tri + rng.normal(0, 1e-6, t.size), force + rng.normal(0, 10.0, t.size)])
        np.savetxt(folder / f"tri_{v * 1e3:.2f}mm_s.csv".replace(".", "p", 1), rows, delimiter=",",
                   header="time_s,displacement_m,force_N", comments="", fmt="%.6f,%.7e,%.3f")
    return folder


def test_saturating_static_characteristic_gives_a_constrained_stage_1_with_a_note(tmp_path):
    """Plateau forces that saturate with speed make the least-squares C_Q of both directions negative: stage 1 holds
    them at 0 and says so (``check``'s note, ``summary["static_constrained"]``), and the run goes on (the diagnosis
    decides what explains it) instead of refusing the data."""
    data = _saturating_data_set(tmp_path / "sat")
    proc = run("check", data, "--tmax", "1.5", "--no-fit")
    assert proc.returncode == 0, proc.stderr
    (note,) = [ln for ln in proc.stdout.splitlines() if "held at 0" in ln]
    assert "C_Q12" in note and "C_Q21" in note and "C_L" not in note
    out = tmp_path / "out"
    proc = run("identify", data, "--out", out, "--tmax", "1.5", "--max-steps", "50", "--only", "tri_1p10mm_s_s1",
               "--workers", "1", "--no-figures")
    assert proc.returncode == 0, proc.stderr
    s = json.loads((out / "summary.json").read_text())
    assert sorted(s["static_constrained"]) == ["C_Q12", "C_Q21"]
    assert s["static"]["CQ12"]["median"] == 0.0 and s["static"]["CQ21"]["median"] == 0.0
    assert s["static"]["CL12"]["median"] > 0 and s["static"]["CL21"]["median"] > 0
    (seg,) = s["segments"]
    assert seg["id"] == "tri_1p10mm_s_s1" and seg["flow_prior"] == "stage 1 (plateaus)"
    # the coefficients held at 0 keep eq. (8)'s sign in the stored draws (the cut draws stage 1's Gaussian
    # restricted to >= 0), so a calibration or prediction built from them is valid
    from bayesdamper.inference.posterior import read_transient

    stored = read_transient(out / "posteriors" / "tri_1p10mm_s_s1.nc")
    flow = stored["chains"][..., [stored["names"].index(n) for n in ("CL12", "CQ12", "CL21", "CQ21")]]
    assert np.all(flow >= 0.0) and np.any(flow[..., 1] > 0.0)
