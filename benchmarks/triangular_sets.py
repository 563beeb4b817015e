"""Write the triangular data sets on which ``benchmarks/diagnose_phases.py`` times a cold diagnose.

Every set is made by the confusion table's reference generator (``tests/test_confusion.py``: the two-state damper of
``tests/reference_effects.py``, written apart from the effect code), 1.25 triangle cycles per test, with at most one
injected rig effect. Most are 33-transient sets at rig-A's eleven speeds (0.5-1.5 mm/s) and its 5 mm amplitude; they
span the rates and sensors the toolkit serves: 200 Hz records with white force noise; 1 kHz, 500 Hz and 100 Hz
records with noise and ADC steps on both channels and an unzeroed load cell (an offset in the data and in the true
force). The ``fast`` sets reach faster speeds (to 2-2.5 mm/s) or a smaller amplitude, so that some ramps are shorter
than the 3 s transient window (the window then ends with its ramp).

    python benchmarks/triangular_sets.py [OUT] [--only NAME ...]
    python benchmarks/diagnose_phases.py OUT/control-200Hz OUT/friction-1kHz ...

OUT defaults to ``/tmp/bayesdamper-sets``; each set is a folder of CSV records and ``damper.toml``, ready for any
command. The seeds are fixed: the same sets on every machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_confusion as tc  # noqa: E402

SPEEDS = tc.ELEVEN_SPEEDS
CLEAN = tc.Channels(speeds=SPEEDS, force_sd=12.0)
ADC_200 = tc.Channels(speeds=SPEEDS, force_sd=12.0, displacement_sd=0.3e-6, force_step=2.0,
                      displacement_step=0.5e-6, offset=40.0)


def _khz(offset: float, rate: float = 1000.0, force_sd: float = 10.0) -> tc.Channels:
    return tc.Channels(rate=rate, speeds=SPEEDS, force_sd=force_sd, displacement_sd=0.3e-6, force_step=4.0,
                       displacement_step=1.0e-6, offset=offset)


VALVE = {"poppet_valve": {"natural_frequency_Hz": 2.0, "damping_ratio": 0.5, "cracking_pressure_Pa": 1.5e4,
                          "span_Pa": 3.0e7}}
VALVE_100 = {"poppet_valve": {"natural_frequency_Hz": 2.2, "damping_ratio": 0.35, "cracking_pressure_Pa": 2.0e4,
                              "span_Pa": 3.0e7}}
FRICTION = {"seal_friction": {"stribeck_N": 200.0, "stribeck_velocity_m_s": 5.0e-3, "viscous_Ns_per_m": 10.0}}
MOUNT = {"series_compliance": {"stiffness_N_per_m": 2.0e7}}
FAST_SPEEDS = tuple(round(float(v), 6) for v in (0.5e-3 + 0.25e-3 * k for k in range(9)))  # 0.5-2.5 mm/s
WIDE_SPEEDS = tuple(round(float(v), 6) for v in (0.3e-3 + (1.7e-3 / 6) * k for k in range(7)))  # 0.3-2.0 mm/s
MOUNT_SPEEDS = tuple(round(float(v), 6) for v in (0.5e-3 + 0.25e-3 * k for k in range(7)))  # 0.5-2.0 mm/s
#: name -> (two-state base, injected effects, channels, seed[, amplitude [m]: rig-A's 5 mm if not given])
SETS = {
    "control-200Hz": (tc.two_state_base(1.3, "gas-a"), {}, CLEAN, 202),
    "mount-200Hz": (tc.two_state_base(1.4, "gas-a"), MOUNT, CLEAN, 202),
    "valve-200Hz-adc": (tc.two_state_base(1.25, "gas-b"), VALVE, ADC_200, 202),
    "friction-200Hz": (tc.two_state_base(1.2, "gas-b"), FRICTION, CLEAN, 202),
    "friction-1kHz": (tc.two_state_base(1.2, "gas-b"), FRICTION, _khz(-150.0), 303),
    "control-1kHz": (tc.two_state_base(1.4, "gas-b"), {}, _khz(-150.0), 303),
    "valve-1kHz": (tc.two_state_base(1.25, "gas-b"), VALVE, _khz(120.0), 404),
    "mount-500Hz": (tc.two_state_base(1.3, "gas-a"), MOUNT, _khz(90.0, 500.0, 12.0), 404),
    "control-100Hz": (tc.two_state_base(1.15, "gas-a"), {}, tc.HUNDRED_HZ, 505),
    "valve-100Hz": (tc.two_state_base(1.35, "gas-a"), VALVE_100, tc.HUNDRED_HZ, 506),
    "mount-100Hz": (tc.two_state_base(1.2, "gas-b"), {"series_compliance": {"stiffness_N_per_m": 1.5e7}},
                    tc.HUNDRED_HZ, 507),
    "control-250Hz-fast": (tc.two_state_base(1.3, "gas-b"), {},
                           tc.Channels(rate=250.0, speeds=WIDE_SPEEDS, force_sd=25.0, displacement_sd=0.4e-6,
                                       force_step=3.0, displacement_step=1.0e-6, offset=-80.0), 808),
    "control-500Hz-3mm": (tc.two_state_base(1.2, "gas-a"), {},
                          tc.Channels(rate=500.0, speeds=SPEEDS, force_sd=12.0, displacement_sd=0.3e-6, force_step=2.0,
                                      displacement_step=0.5e-6, offset=30.0), 809, 3.0e-3),
    "valve-200Hz-fast": (tc.two_state_base(1.3, "gas-b"), VALVE,
                         tc.Channels(speeds=FAST_SPEEDS, force_sd=12.0, displacement_sd=0.3e-6, force_step=2.0,
                                     displacement_step=0.5e-6, offset=50.0), 811),
    "mount-1kHz-4mm": (tc.two_state_base(1.2, "gas-a"), MOUNT,
                       tc.Channels(rate=1000.0, speeds=MOUNT_SPEEDS, force_sd=10.0, displacement_sd=0.3e-6,
                                   force_step=4.0, displacement_step=1.0e-6, offset=-120.0), 812, 4.0e-3),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", nargs="?", default="/tmp/bayesdamper-sets", help="folder to write the sets into")
    ap.add_argument("--only", nargs="+", choices=sorted(SETS), help="write only these sets")
    args = ap.parse_args(argv)
    for name in args.only or SETS:
        base, effects, channels, seed, *amplitude = SETS[name]
        t0 = time.perf_counter()
        kept, tc.AMPLITUDE = tc.AMPLITUDE, amplitude[0] if amplitude else tc.AMPLITUDE
        try:
            folder, _ = tc._dataset(Path(args.out) / name, effects, 1.25, seed=seed, base=base, ch=channels)
        finally:
            used, tc.AMPLITUDE = tc.AMPLITUDE, kept
        print(f"{name}: {channels.rate:g} Hz, {len(channels.speeds)} speeds "
              f"({min(channels.speeds) * 1e3:g}-{max(channels.speeds) * 1e3:g} mm/s), amplitude {used * 1e3:g} mm, "
              f"effects {sorted(effects) or 'none'}, offset {channels.offset:g} N, seed {seed} -> {folder} "
              f"({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
