"""One line per (configuration, seed set) of table.py's results: cells
meeting the goal (report.py's check) among the stable ones, the worst
relative Lhh error of the paper's stage 1 and of the proposed one, the worst
|Lhx^| and |Lhv^ - Lhv| of the proposed one, the delay errors, stage 2's
RMSE and stage 3's ratio.

    .venv/bin/python benches/partner_delay/summary.py
"""
import glob
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from report import gain_ok

RES = Path(__file__).resolve().parent / "results"
CFGS = ["paper_km0", "paper_km0.1", "damped_km0", "damped_km0.1", "damped_km0.3", "damped_km0.1_drift0.1"]


def main():
    print("| partner | k_m | drift | seeds | goal met (stable cells) | unstable cells | paper Lhh worst err | proposed Lhh worst err | "
          "proposed worst abs(Lhx^) / Lhh | proposed worst Lhv err | worst d_v err (ms) | d_p: identified when Lhv > 0 / "
          "worst err (ms) / flagged when Lhv = 0 | stage-2 RMSE vs tau_h[k-d_v], d-a (deg) | stage-3 own/int at d_v = 0, paper / d-a | at d_v >= 50 |")
    print("|" + "---|" * 15)
    for cfg in CFGS:
        for tag in ("tune", "unseen"):
            files = sorted(glob.glob(str(RES / f"{tag}_{cfg}_s*.json")))
            if not files:
                continue
            rs = [r for f in files for r in json.load(open(f))["results"] if not (r["lhv"] == 0 and r["dp_true"] != 0)]
            seeds = sorted({r["seed"] for r in rs})
            cells = defaultdict(list)
            for r in rs:
                cells[(r["lhh"], r["dp_true"], r["dv_true"])].append(r)
            st = [c for c in cells.values() if all(r["stable"] for r in c)]
            uns = [k for k, c in cells.items() if not all(r["stable"] for r in c)]

            def ok(c):
                r0 = c[0]
                g = all(gain_ok(r["stage1"]["dl_q"]["mean"], r["gains_true"], r["lhh"]) for r in c)
                dv = all(abs(r["chosen"][0] - r["dv_true"]) <= 10 for r in c)
                dp = r0["lhv"] == 0 or all(r["dp_identified"] and abs(r["chosen"][1] - r["dp_true"]) <= 10 for r in c)
                return g and dv and dp

            srs = [r for c in st for r in c]
            err = lambda m: max(abs(r["stage1"][m]["mean"][2] - r["gains_true"][2]) / r["lhh"] for r in srs)
            lhx = max(abs(r["stage1"]["dl_q"]["mean"][0]) / r["lhh"] for r in srs)
            lhv = max(abs(r["stage1"]["dl_q"]["mean"][1] - r["gains_true"][1]) / (r["gains_true"][1] or np.sqrt(2 * 0.0035 * r["lhh"])) for r in srs)
            dve = max(abs(r["chosen"][0] - r["dv_true"]) for r in srs)
            withv = [r for r in srs if r["lhv"] > 0]
            dpi = f"{sum(r['dp_identified'] for r in withv)}/{len(withv)} / {max((abs(r['chosen'][1] - r['dp_true']) for r in withv), default=0)}" if withv else "-"
            nov = [r for r in srs if r["lhv"] == 0]
            dpi += f" / {sum(r['dp_identified'] for r in nov)} of {len(nov)}" if nov else ""
            r2 = [r["rmse2_dl_delayed"] for r in srs]
            z = [r for r in srs if r["dv_true"] == 0]
            nz = [r for r in srs if r["dv_true"] >= 50]
            rat = lambda rr, o, f: (min(r[o] / r[f] for r in rr), max(r[o] / r[f] for r in rr))
            a, b = rat(z, "s3_paper_own", "s3_paper_fused"), rat(z, "s3_dl_own", "s3_dl_fused")
            c, d = rat(nz, "s3_paper_own", "s3_paper_fused"), rat(nz, "s3_dl_own", "s3_dl_fused")
            fam, rest = cfg.split("_", 1)
            km = rest.split("_")[0][2:]
            drift = rest.split("drift")[1] if "drift" in rest else "0"
            print(f"| {fam} | {km} | {drift} | {tag} {seeds} | {sum(ok(c) for c in st)}/{len(st)} | {len(uns)} | "
                  f"{100 * err('paper_Q'):.0f}% | {100 * err('dl_q'):.1f}% | {100 * lhx:.1f}% | {100 * lhv:.1f}% | {dve} | {dpi} | "
                  f"{min(r2):.3f}-{max(r2):.3f} | {a[0]:.2f}-{a[1]:.2f} / {b[0]:.2f}-{b[1]:.2f} | {c[0]:.2f}-{c[1]:.2f} / {d[0]:.2f}-{d[1]:.2f} |")


if __name__ == "__main__":
    main()
