"""The issue-24 table: what the delay-aware identification buys against the
paper's model, with a human-like partner (docs/model.md, "A partner with a
delay"; the design and its choices: docs/design/partner_delay.md).

Cells: visual delay d_v in {0, 50, 100, 150, 200} ms x proprioceptive delay
d_p in {0, 40} ms x Lhh in {0.5, 1, 2}, for two partner families:

* "paper": the paper's virtual human L_h = [0, 0, Lhh] (no velocity term, so
  d_p acts on a zero term: run at d_p = 0 only, and d_p is not identifiable);
* "damped": L_h = [0, sqrt(2 M Lhh), Lhh], the velocity gain an LQR partner
  with q_vel = 0 has at that stiffness (the robot's own rule).

Every trial is the Hi5 experiment (presets.hi5_experiment: 20 s gains,
trajectory and integration phases) with partner.human = {d_v, d_p,
motor_noise_gain = 0.1} and the seed given to the world, the robot and the
partner. Two robots per cell:

* paper: the preset unchanged (robot.partner_delay absent);
* aware: robot.partner_delay = "auto" and stage 1's gain process noise 1e-6
  per step (the preset's 1e-2 makes stage 1 biased for any partner with
  signal-dependent motor noise, delayed or not: design note section 5).

Columns: the Lhh estimate (mean of the last 8 s of the gain phase) and its
oscillation (std within those 8 s) for each robot; the identified delays
against the true ones; the goal check (every gain within 5% of the truth --
an absent gain within 5% of the stiffness's scale -- and the delays within
10 ms); the stage-2 partner-target RMSE (aware: against tau_h now and
against tau_h[k - d_v], what a delayed partner's target estimate is); the
stage-3 ratio own / integrated RMSE (> 1: goal integration helps). A cell
whose closed loop (robot + delayed partner, noise-free) is unstable is
reported as such and not run.

    .venv/bin/python -m sensaug.partner_delay --seeds 300 301 302 [--out FILE.md]

prints the Markdown table (one row per cell and seed); `sensaug figures`
adds it to REPORT.md (`--quick`: the reduced cells, one seed).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from sensaug import experiment, presets
from sensaug.config_types import HumanConfig

VISUAL_MS = (0, 50, 100, 150, 200)
PROPRIOCEPTIVE_MS = (0, 40)
LHH = (0.5, 1.0, 2.0)
#: The partner's signal-dependent motor noise in every cell.
MOTOR_NOISE_GAIN = 0.1
#: Stage 1's gain process noise per step for the delay-aware robot.
AWARE_GAIN_Q = 1e-6


@dataclass(frozen=True)
class Loop:
    """The closed loop's numbers: the handle's inertia, the robot's LQR gains, dt."""

    M: float
    kp: float
    kv: float
    dt: float


def loop() -> Loop:
    cfg = presets.hi5_experiment(1.0)
    M, C = cfg.plant.mass, cfg.plant.damping
    assert C == 0.0
    q_pos, q_vel = cfg.robot.q_pos, cfg.robot.q_vel
    # The reduced 2-state LQR of docs/model.md, closed form for C = 0.
    kp = math.sqrt(q_pos)
    return Loop(M, kp, math.sqrt(q_vel + 2 * M * kp), cfg.plant.dt_s)


def partner_gains(family: str, lhh: float) -> list[float]:
    if family == "paper":
        return [0.0, 0.0, lhh]
    return [0.0, math.sqrt(2 * loop().M * lhh), lhh]


def spectral_radius(gains, dv: int, dp: int) -> float:
    """Spectral radius of the noise-free 1 kHz closed loop (targets at rest)
    with the partner's delays as shift registers: ``x' = x + dt v + dt^2 f /
    (2M)``, ``v' = v + dt f / M``, ``f = -kp x[k] - kv v[k] - (Lhx + Lhh)
    x[k - dv] - Lhv v[k - dp]``; delays in ticks."""
    h = loop()
    lhx, lhv, lhh = gains
    nx, nv = dv + 1, dp + 1
    n = nx + nv
    A = np.zeros((n, n))
    f = np.zeros(n)
    f[0] -= h.kp
    f[nx] -= h.kv
    f[dv] -= lhx + lhh
    f[nx + dp] -= lhv
    A[0] = 0.5 * h.dt * h.dt / h.M * f
    A[0, 0] += 1.0
    A[0, nx] += h.dt
    A[nx] = h.dt / h.M * f
    A[nx, nx] += 1.0
    for i in range(1, nx):
        A[i, i - 1] = 1.0
    for i in range(1, nv):
        A[nx + i, nx + i - 1] = 1.0
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def closed_loop_stable(family: str, dv_ms: float, dp_ms: float, lhh: float) -> bool:
    dt = loop().dt
    return spectral_radius(partner_gains(family, lhh), round(dv_ms * 1e-3 / dt), round(dp_ms * 1e-3 / dt)) < 1.0


def config(family: str, dv: float, dp: float, lhh: float, seed: int, *, aware: bool, phase_s: float):
    cfg = presets.hi5_experiment(lhh, seed=seed, phase_s=phase_s)
    cfg.partner.gains = partner_gains(family, lhh)
    cfg.partner.human = HumanConfig(
        visual_delay_ms=float(dv), proprioceptive_delay_ms=float(dp), motor_noise_gain=MOTOR_NOISE_GAIN, seed=seed
    )
    cfg.world.seed = seed
    cfg.robot.seed = seed
    if aware:
        cfg.robot.partner_delay = "auto"
        q = list(cfg.robot.stage1.Q)
        cfg.robot.stage1.Q = q[:3] + [AWARE_GAIN_Q] * 3
    return cfg


def goal(gains: np.ndarray, truth: list[float]) -> bool:
    """Every gain within 5% of the truth; an absent gain (truth 0) within 5%
    of its scale (Lhx: Lhh; Lhv: sqrt(2 M Lhh), the damped family's)."""
    lhh = truth[2]
    scale = [lhh, truth[1] or math.sqrt(2 * loop().M * lhh), lhh]
    return all(abs(g - t) <= 0.05 * s for g, t, s in zip(gains, truth, scale))


def measure(trial, dv: float, aware: bool, gain_s: float) -> dict:
    d = trial.data
    gains = trial.gain_estimate(0)
    last = trial.phase_mask(0, last_s=min(8.0, gain_s))
    out = {
        "gains": gains,
        "osc": float(np.std(d["Lhh_hat"][last])),
        "rmse_now": trial.partner_target_rmse(1),
        "ratio": None,
    }
    integ = trial.integration_rmse(2)
    out["ratio"] = integ["own"] / integ["integrated"]
    if aware:
        end = np.flatnonzero(trial.phase_mask(0))[-1]
        out["dv_ms"] = float(d["partner_delay_visual_ms"][end])
        out["dp_ms"] = float(d["partner_delay_proprioceptive_ms"][end])
        out["margin"] = float(d["partner_delay_margin_nats"][end])
        # tau_h^ estimates the target the partner perceives, d_v ago.
        m = trial.phase_mask(1, skip_s=2.0)
        k = np.flatnonzero(m)
        lag = round(dv * 1e-3 / trial.config.plant.dt_s)
        out["rmse_lagged"] = float(np.sqrt(np.mean((d["tau_h_hat"][k] - d["tau_h"][k - lag]) ** 2)))
    return out


def run_cell(family: str, dv: float, dp: float, lhh: float, seed: int, *, phase_s: float = 20.0) -> dict:
    row = {"family": family, "dv": dv, "dp": dp, "lhh": lhh, "seed": seed,
           "stable": closed_loop_stable(family, dv, dp, lhh)}  # fmt: skip
    if not row["stable"]:
        return row
    truth = partner_gains(family, lhh)
    for name, aware in (("paper", False), ("aware", True)):
        trial = experiment.run(config(family, dv, dp, lhh, seed, aware=aware, phase_s=phase_s))
        m = measure(trial, dv, aware, phase_s)
        ok = goal(m["gains"], truth)
        if aware:
            ok = ok and abs(m["dv_ms"] - dv) <= 10
            if family == "damped":
                ok = ok and abs(m["dp_ms"] - dp) <= 10
        m["goal"] = bool(ok)
        row[name] = m
    return row


#: The reduced table (the tests' and `sensaug figures --quick`'s): the
#: damped partner at d_p = 40 ms across the visual delays, the paper's
#: virtual human at a long delay, and an unstable cell.
REDUCED = (
    ("damped", 0, 40, 1.0),
    ("damped", 100, 40, 1.0),
    ("damped", 200, 40, 1.0),
    ("paper", 150, 0, 0.5),
    ("paper", 100, 0, 2.0),
)


def cells():
    for family in ("paper", "damped"):
        for lhh in LHH:
            for dv in VISUAL_MS:
                for dp in PROPRIOCEPTIVE_MS if family == "damped" else (0,):
                    yield family, dv, dp, lhh


HEADER = (
    "| partner | Lhh | d_v | d_p | seed | paper: Lhh^ (osc) | paper goal | aware: Lhx^, Lhv^, Lhh^ (osc) "
    "| aware d_v^, d_p^ (margin) | aware goal | stage 2 RMSE paper / aware now / aware lagged | "
    "stage 3 own/integrated paper / aware |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def fmt(row: dict) -> str:
    head = f"| {row['family']} | {row['lhh']:g} | {row['dv']:g} | {row['dp']:g} | {row['seed']} "
    if not row["stable"]:
        return head + "| **unstable closed loop: not run** | | | | | | |"
    p, a = row["paper"], row["aware"]
    dp = "n/i" if math.isnan(a["dp_ms"]) else f"{a['dp_ms']:g}"
    return (
        head
        + f"| {p['gains'][2]:.3f} ({p['osc']:.3f}) | {'yes' if p['goal'] else 'no'} "
        + f"| {a['gains'][0]:.4f}, {a['gains'][1]:.4f}, {a['gains'][2]:.3f} ({a['osc']:.4f}) "
        + f"| {a['dv_ms']:g}, {dp} ({a['margin']:.0f}) | {'yes' if a['goal'] else 'no'} "
        + f"| {p['rmse_now']:.2f} / {a['rmse_now']:.2f} / {a['rmse_lagged']:.2f} "
        + f"| {p['ratio']:.2f} / {a['ratio']:.2f} |"
    )


def table(seeds, phase_s: float = 20.0, progress=None, *, reduced: bool = False) -> str:
    lines = [HEADER]
    rows = []
    for family, dv, dp, lhh in REDUCED if reduced else cells():
        for seed in seeds:
            row = run_cell(family, dv, dp, lhh, seed, phase_s=phase_s)
            rows.append(row)
            lines.append(fmt(row))
            if progress:
                progress(lines[-1])
    stable = [r for r in rows if r["stable"]]
    met = sum(r["aware"]["goal"] for r in stable)
    paper_met = sum(r["paper"]["goal"] for r in stable)
    lines.append("")
    lines.append(
        f"Stable trials: {len(stable)} of {len(rows)}; goal met by the delay-aware robot in {met}, "
        f"by the paper's model in {paper_met}. Seeds {', '.join(map(str, seeds))}; {phase_s:g} s phases; "
        f"partner motor noise gain {MOTOR_NOISE_GAIN}."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[300, 301])
    ap.add_argument("--phase-s", type=float, default=20.0)
    ap.add_argument("--out", help="also write the table to this Markdown file")
    ap.add_argument("--reduced", action="store_true", help="only the reduced table's cells")
    args = ap.parse_args(argv)
    text = table(args.seeds, args.phase_s, progress=lambda line: print(line, file=sys.stderr, flush=True),
                 reduced=args.reduced)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
