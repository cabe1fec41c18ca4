"""What the live view streams during a virtual-rig run with the person-like
partner (configs/hi5_rig_person.toml), drawn (docs/live_view.png).

Foxglove's app cannot run on this machine (docs/live.md), so this draws,
with matplotlib, exactly the messages a Foxglove WebSocket client received
from `sensaug live` while the demo's virtual rig ran: the layout's panels,
each decimated series with its bin's min/max envelope where the layout has
one. Usage: `.venv/bin/python scripts/live_picture.py [OUT.png] [phase_s]`.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sensaug import presets, rig  # noqa: E402
from sensaug.export import RUN_TOPIC  # noqa: E402
from sensaug.live import Client, LiveView  # noqa: E402


def series(client: Client, topic: str, field: str) -> tuple[np.ndarray, np.ndarray]:
    msgs = client.topic(topic)
    t = np.array([m["t"] for _, m in msgs])
    v = np.array([np.nan if m[field] is None else float(m[field]) for _, m in msgs])
    return t, v


def _clip_outliers(ax) -> None:
    """Keeps the bulk of a panel readable: y limits from the 0.5-99.5th
    percentiles of its lines (widened by half their span), and a note of the
    values off that scale (a diverging estimate is shown, not hidden)."""
    values = np.concatenate([ln.get_ydata() for ln in ax.get_lines()])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return
    lo, hi = np.percentile(values, [0.5, 99.5])
    pad = 0.5 * max(hi - lo, 1e-9)
    lo, hi = lo - pad, hi + pad
    off = values[(values < lo) | (values > hi)]
    if off.size:
        ax.set_ylim(lo, hi)
        ax.text(0.01, 0.02, f"{off.size} bins off scale (min {values.min():.3g}, max {values.max():.3g})",
                transform=ax.transAxes, fontsize=7, color="firebrick")


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/live_view.png")
    phase_s = float(sys.argv[2]) if len(sys.argv) > 2 else 10.0
    # The person-like partner (configs/hi5_rig_person.toml): the robot
    # finds its delays online, so the partner-delay panel has something to show.
    cfg = presets.hi5_person(phase_s=phase_s)
    cfg.rig.feedback_timeout_ms, cfg.rig.watchdog_ms = 300.0, 200  # the widest: a loaded VM
    # A loaded shared machine stalls the loop or the Python drive for tens
    # of ms now and then (tests/test_rig.py::stall_tolerant): the picture is
    # of the live view, not of the degraded-run thresholds.
    cfg.rig.max_stale_feedback_ticks, cfg.rig.max_missing_feedback_fraction = 300, 1.0
    with LiveView(feed_port=0, port=0) as view, tempfile.TemporaryDirectory() as tmp:
        view.serve_in_thread()
        client = Client(view.url)
        run = rig.run_virtual_rig(cfg, out=Path(tmp), capture=None, feed=[view.reader.address])
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not any(m["status"] == "ended" for _, m in client.topic(RUN_TOPIC)):
            time.sleep(0.1)
        client.close()
    end = [m for _, m in client.topic(RUN_TOPIC)][-1]
    panels = [
        ("Handle and targets [deg]", [("/handle", "x"), ("/targets", "tau"), ("/targets", "tau_h"),
                                      ("/partner_target", "tau_h_hat")], None),
        ("Partner gains (estimates)", [("/partner_gains", "Lhx_hat"), ("/partner_gains", "Lhv_hat"),
                                       ("/partner_gains", "Lhh_hat")], None),
        ("Goal integration: (x - tau) [deg]", [("/targets", "e"), ("/goal_integration", "e_hat_own"),
                                               ("/goal_integration", "e_hat_fused")], None),
        ("Torque sent [N m] (line: value at bin end; band: bin min..max)", [("/torque", "torque_nm")], "band"),
        ("Loop compute [us] (bin max and value at bin end)", [("/loop", "compute_us_max"), ("/loop", "compute_us")], None),
        ("Missing feedback: ticks since the last (bin max)", [("/safety", "feedback_age_ticks_max")], None),
        ("Partner delay assumed [ms] (robot.partner_delay = \"auto\")",
         [("/partner_delay", "partner_delay_visual_ms"), ("/partner_delay", "partner_delay_proprioceptive_ms")], None),
        ("Delay search: margin of the chosen visual delay [nats]",
         [("/partner_delay", "partner_delay_margin_nats")], None),
    ]
    fig, axes = plt.subplots(4, 2, figsize=(13, 11.5), sharex=True)
    for ax, (title, paths, band) in zip(axes.T.ravel(), panels):
        for topic, field in paths:
            t, v = series(client, topic, field)
            ax.plot(t, v, lw=0.9, label=f"{topic}.{field}")
            if band:
                _, lo = series(client, topic, field + "_min")
                _, hi = series(client, topic, field + "_max")
                ax.fill_between(t, lo, hi, alpha=0.35, step="post", label=f"{topic}.{field}_min..max")
        _clip_outliers(ax)
        for k in range(1, 3):
            ax.axvline(k * phase_s, color="0.6", lw=0.6, ls=":")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("run time t [s] (dotted: phase changes)")
    n = len(client.topic("/handle"))
    fig.suptitle(f"sensaug live view of a person-like partner's run (configs/hi5_rig_person.toml), as received by a Foxglove WebSocket client: {n} messages per topic "
                 f"({n / run.log['t'][-1]:.0f} Hz)\nstop: {end['stop_reason']}", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    print(f"{out}: {n} messages per topic over {run.log['t'][-1]:.1f} s; stop {end['stop_reason']}")


if __name__ == "__main__":
    main()
