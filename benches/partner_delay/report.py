"""Markdown tables from table.py's JSON results.

    .venv/bin/python benches/partner_delay/report.py results/a.json [results/b.json ...]

Per cell, over the seeds in the files: the estimated gains (mean over seeds of
each trial's mean over the last 8 s of the gain phase; "osc" is the mean
within-trial std over those 8 s), the worst error over seeds, the chosen
delays against the truth, stage 2's partner-target RMSE and stage 3's
own / integrated RMSE ratio.

The goal check ("ok"): for every seed, |Lhh^ - Lhh| <= 5% Lhh, a zero
position gain Lhx within 5% of Lhh, Lhv within 5% of its truth when it is
non-zero, else within 5% of sqrt(2 M Lhh) (the velocity gain an LQR
partner would have at that stiffness); the chosen dv within 10 ms, and dp
within 10 ms when the partner has a velocity term (else it is not
identifiable and reported as "n/i").
"""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict

import numpy as np

M = 0.0035


def gain_ok(est, truth, lhh):
    tol_pos = 0.05 * lhh
    lhv_scale = truth[1] if truth[1] != 0 else math.sqrt(2 * M * lhh)
    return (abs(est[0] - truth[0]) <= tol_pos and abs(est[2] - truth[2]) <= 0.05 * abs(truth[2])
            and abs(est[1] - truth[1]) <= 0.05 * lhv_scale)


def main(paths):
    rows = defaultdict(list)
    meta = []
    for p in paths:
        d = json.load(open(p))
        meta.append((p, d["args"]))
        for r in d["results"]:
            if r["lhv"] == 0 and r["dp_true"] != 0:
                continue  # no velocity term: identical to d_p = 0 (table.py runs only d_p = 0 for it)
            rows[(r["lhh"], r["lhv"], r["dp_true"], r["dv_true"])].append(r)
    seeds = sorted({r["seed"] for v in rows.values() for r in v})
    print(f"seeds: {seeds}; files: {[m[0] for m in meta]}\n")
    print("| Lhh | Lhv | dp | dv | loop | paper, Q_k: Lhh^ (worst err) osc | paper, small q: Lhh^ (worst) | "
          "delay-aware, Q_k: Lhh^ (worst) osc | delay-aware, small q: Lhh^ (worst) osc | its Lhx^, Lhv^ | LS worst err | "
          "chosen dv / dp (ms) | goal | stage-2 RMSE paper / d-a now / d-a delayed (deg) | stage-3 own/int paper / d-a |")
    print("|" + "---|" * 16)
    n_ok = n_stable = 0
    for key in sorted(rows):
        lhh, lhv, dp, dv = key
        rs = rows[key]
        stable = all(r["stable"] for r in rs)
        tru = np.array([r["gains_true"] for r in rs])

        def col(m, osc=True):
            g = np.array([r["stage1"][m]["mean"] for r in rs])
            err = np.abs(g[:, 2] - tru[:, 2]).max() / lhh
            s = f"{g[:, 2].mean():.3f} ({100 * err:.1f}%)"
            if osc:
                s += f" {np.mean([r['stage1'][m]['std'][2] for r in rs]):.3f}"
            return s

        dm = np.array([r["stage1"]["dl_q"]["mean"] for r in rs])
        ls = np.array([r.get("gains_ls", [np.nan] * 3) for r in rs])
        ls_err = np.abs(ls[:, 2] - tru[:, 2]).max() / lhh
        ch = np.array([r["chosen"] for r in rs])
        ident = [r.get("dp_identified", True) for r in rs]
        dv_ok = np.all(np.abs(ch[:, 0] - dv) <= 10)
        if lhv != 0:
            dp_ok = all(ident) and np.all(np.abs(ch[:, 1] - dp) <= 10)
            dps = "/".join(str(c) for c in sorted(set(ch[:, 1].tolist())))
        else:
            dp_ok = True
            dps = "n/i" if not any(ident) else "/".join(("" if i else "n/i:") + str(c) for c, i in zip(ch[:, 1], ident))
        dvs = "/".join(str(c) for c in sorted(set(ch[:, 0].tolist())))
        g_ok = all(gain_ok(r["stage1"]["dl_q"]["mean"], r["gains_true"], lhh) for r in rs)
        ok = g_ok and dv_ok and dp_ok
        if stable:
            n_stable += 1
            n_ok += ok
        r2 = lambda f: np.mean([r[f] for r in rs])
        ratio = lambda o, f: np.mean([r[o] / r[f] for r in rs])
        print(f"| {lhh} | {lhv:.3f} | {dp} | {dv} | {'stable' if stable else '**unstable**'} | "
              f"{col('paper_Q')} | {col('paper_q', False)} | {col('dl_Q')} | {col('dl_q')} | "
              f"{dm[:, 0].mean():+.3f}, {dm[:, 1].mean():+.4f} | {100 * ls_err:.1f}% | "
              f"{dvs} / {dps} | {'ok' if ok else ('FAIL' if stable else '(unstable)')} | "
              f"{r2('rmse2_paper'):.2f} / {r2('rmse2_dl_now'):.2f} / {r2('rmse2_dl_delayed'):.3f} | "
              f"{ratio('s3_paper_own', 's3_paper_fused'):.2f} / {ratio('s3_dl_own', 's3_dl_fused'):.2f} |")
    print(f"\ngoal met in {n_ok} of {n_stable} stable cells (every seed)")


if __name__ == "__main__":
    main(sys.argv[1:])
