"""The partner-gain error on a frictional handle, without and with the
friction compensation (issue 21, docs/hardware.md "Calibrating the handle").

For each seed, on the virtual rig (Hi5 profile), the ``hi5_rig`` preset
(partner gains [0, 0, 2]) is run three times:

The runs use the rig tests' SCHED_FIFO priority and stall-tolerant limits
(tests/test_rig.py), so a loaded machine does not stop them.

* ``frictionless``: the drive's handle as the model has it (M = 0.0035,
  no friction): the estimators' own error, the reference;
* ``uncompensated``: the drive simulates a frictional handle (M = 0.0035,
  C and F_c below, given to the drive process only), compensation off;
* ``compensated``: the same handle, after ``sensaug calibrate``'s excitation
  and identification on it (seed ``100 + seed``), the loop compensating the
  identified C and F_c (``calibrated_config``: plant.mass and rig.friction
  from the estimate).

Prints, per run, the mean estimated gains over the gain window and their
errors against the truth, then the mean absolute errors per condition.

    .venv/bin/python scripts/measure_friction_compensation.py [--seeds 0 1 2]
        [--damping 0.01] [--coulomb 0.02] [--out out/friction]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sensaug import presets, rig
from sensaug.calibrate import calibrated_config, drive_handle_args, run_calibration

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from test_rig import RIG_TEST_FIFO_PRIORITY, stall_tolerant  # noqa: E402


def gains_error(run: rig.RigRun) -> tuple[np.ndarray, np.ndarray]:
    est = run.gain_estimate()
    return est, est - np.asarray(run.config.partner.gains, dtype=float)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--mass", type=float, default=0.0035, help="the handle's inertia, kg m^2 (default 0.0035)")
    ap.add_argument("--damping", type=float, default=0.01, help="the handle's viscous C, N m s/rad (default 0.01)")
    ap.add_argument("--coulomb", type=float, default=0.02, help="the handle's Coulomb F_c, N m (default 0.02)")
    ap.add_argument("--band", type=float, default=None, help="rig.friction.coulomb_band_rad_s (default the schema's)")
    ap.add_argument("--torque-band", type=float, default=None,
                    help="rig.friction.coulomb_torque_band_nm (default the schema's)")
    ap.add_argument("--out", type=Path, default=Path("out/friction"))
    args = ap.parse_args()
    handle = (args.mass, args.damping, args.coulomb)
    print(f"hidden handle: M = {args.mass} kg m^2, C = {args.damping} N m s/rad, F_c = {args.coulomb} N m; "
          f"hi5_rig preset, partner gains [0, 0, 2]; seeds {args.seeds}; bands: {args.band or 'default'} rad/s, "
          f"{args.torque_band or 'default'} N m")
    rows: dict[str, list[np.ndarray]] = {"frictionless": [], "uncompensated": [], "compensated": []}
    print(f"{'seed':>4} {'condition':>14} {'Lhx^':>9} {'Lhv^':>9} {'Lhh^':>9} {'Lhh err':>9}  stop")
    for seed in args.seeds:
        out = args.out / f"seed{seed}"
        # As the rig tests run (SCHED_FIFO when allowed, stall-tolerant
        # limits on a loaded machine), the same for the three runs.
        base = stall_tolerant(presets.hi5_rig(seed=seed))
        base.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
        if args.band is not None:
            base.rig.friction.coulomb_band_rad_s = args.band
        if args.torque_band is not None:
            base.rig.friction.coulomb_torque_band_nm = args.torque_band
        est, _ = run_calibration(base, out=out / "calibration", seed=100 + seed, handle=handle)
        print(f"     identified: M = {est.mass.value:.6g}, C = {est.damping.value:.6g}, F_c = {est.coulomb.value:.6g}")
        runs = {
            "frictionless": rig.run_virtual_rig(base, out=out / "frictionless", capture=None, stop_key=False),
            "uncompensated": rig.run_virtual_rig(base, out=out / "uncompensated", capture=None, stop_key=False,
                                                 drive_args=drive_handle_args(*handle)),
            "compensated": rig.run_virtual_rig(calibrated_config(base, est), out=out / "compensated", capture=None,
                                               stop_key=False, drive_args=drive_handle_args(*handle)),
        }  # fmt: skip
        for name, run in runs.items():
            g, err = gains_error(run)
            rows[name].append(err)
            print(f"{seed:>4} {name:>14} {g[0]:9.4f} {g[1]:9.4f} {g[2]:9.4f} {err[2]:+9.4f}  {run.stats['stop_reason']}")
    print("\nmean |error| over the seeds (Lhx N m/rad, Lhv N m s/rad, Lhh N m/rad):")
    for name, errs in rows.items():
        e = np.abs(np.asarray(errs)).mean(axis=0)
        print(f"  {name:>14}: Lhx {e[0]:.4f}  Lhv {e[1]:.4f}  Lhh {e[2]:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
