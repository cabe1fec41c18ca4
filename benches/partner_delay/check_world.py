"""The batched world's partner equals the one-tick oracle (same draws)."""
import sys
from pathlib import Path

import numpy as np

from settings import hi5
from world import World

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "oracles"))
from human_partner import HumanPartner, HumanSettings  # noqa: E402

h = hi5(phase_s=2.0)
ps = [HumanSettings((0.0, 0.1, 1.0), 120, 40, 0.1, 0.2, 0.5, seed=5), HumanSettings((0.3, 0.0, 2.0), 30, 0, 0.0, 0.0, seed=6)]
w = World(h, ps, [11, 12])
w.run_open(2 * h.ticks)
for b, p in enumerate(ps):
    o = HumanPartner(p, h.dt, 3 * h.ticks)
    worst = 0.0
    for k in range(2 * h.ticks):
        u = o.torque(k, w.rec["xm"][b, k], w.rec["vm"][b, k], w.tau[k], w.tau_h[k])
        worst = max(worst, abs(u - w.rec["u_h"][b, k]))
    print(f"partner {b}: worst |batched - oracle| torque = {worst:.2e}")
    assert worst < 1e-12
