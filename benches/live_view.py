"""The rig loop with and without the live view, side by side in one run.

`python benches/live_view.py [round_s] [rounds]` prints the table;
`benches/report.py` puts it into BENCHMARKS.md (docs/live.md quotes it).

Three kinds of round, each a virtual-rig run of the Hi5 protocol
(`presets.hi5_rig` with `round_s / 3` s phases: sensaug-rt at 1 kHz, the
virtual drive; the feedback timeout, watchdog and stale-feedback limit at
300 ms, 200 ms, 1000 ticks so a stall of the shared machine ends fewer
rounds early — a gap of more than ~100 ticks still makes the estimators
diverge, docs/safety.md, and the round then stops on estimator errors: the
table's last column lists every round's stop), interleaved A B C C B A ... so a drift in
the shared machine's load hits all alike:

- *no viewer*: no `--feed`, no live view;
- *viewer*: `sensaug-rt --feed` to a `sensaug live` process (its own
  process, the Foxglove SDK's WebSocket server, 100 Hz per topic) with a
  Foxglove WebSocket client connected, subscribed to every channel, reading;
- *stalled viewer*: the same, the client subscribed but never reading (a
  frozen viewer: the server's per-client backlog fills and drops).

Per kind, pooled over its rounds: the loop's compute per tick (`compute_us`
column: wake-up to command sent) p50/p99/p99.9, its wake-up latency p50/p99,
deadline misses and ring overflows (the statistics JSON), the feed's
datagrams sent and dropped (the log's end line), and the live view
process's peak resident memory (VmHWM) and the messages its client received.
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROUND_S = 6.0
ROUNDS = 4
KINDS = ("no viewer", "viewer", "stalled viewer")


def _peak_rss_kib(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def one_round(kind: str, round_s: float, out: Path) -> dict:
    from sensaug import presets, rig
    from sensaug.live import Client, LiveProcess

    cfg = presets.hi5_rig(phase_s=round_s / 3)
    # The widest feedback limits, so a stall of the shared machine does not
    # end a round early: the subject is the loop's own time, not the drive's.
    cfg.rig.feedback_timeout_ms, cfg.rig.watchdog_ms, cfg.rig.max_stale_feedback_ticks = 300.0, 200, 1000
    viewer = client = None
    feed: list[str] = []
    if kind != "no viewer":
        viewer = LiveProcess(port=0)
        client = Client(viewer.url, stall=(kind == "stalled viewer"))
        feed = [viewer.feed_address]
    try:
        run = rig.run_virtual_rig(cfg, out=out, capture=None, feed=feed)
        rss = _peak_rss_kib(viewer.proc.pid) if viewer else None
        received = len(client.messages) if client else 0
    finally:
        if client is not None:
            client.close()
        if viewer is not None:
            viewer.stop()
    end = run.log.meta.get("end", {})
    return {
        "compute_us": run.log["compute_us"],
        "wake_us": run.log["wake_latency_us"],
        "deadline_misses": run.stats["deadline_misses"],
        "ring_overflows": run.stats["ring_overflows"],
        "stop_reason": run.stats["stop_reason"],
        "feed_sent": end.get("feed_datagrams_sent", 0),
        "feed_dropped": end.get("feed_datagrams_dropped", 0),
        "viewer_peak_rss_kib": rss,
        "messages_received": received,
        "ticks": len(run.log),
    }


def compare(round_s: float = ROUND_S, rounds: int = ROUNDS) -> dict:
    order = []
    for r in range(rounds):
        order += list(KINDS) if r % 2 == 0 else list(reversed(KINDS))
    results: dict[str, list[dict]] = {k: [] for k in KINDS}
    with tempfile.TemporaryDirectory(prefix="sensaug-live-bench-") as tmp:
        for i, kind in enumerate(order):
            results[kind].append(one_round(kind, round_s, Path(tmp) / f"r{i}"))
    pooled = {}
    for kind, rs in results.items():
        compute = np.concatenate([r["compute_us"] for r in rs])
        wake = np.concatenate([r["wake_us"] for r in rs])
        compute, wake = compute[np.isfinite(compute)], wake[np.isfinite(wake)]
        rss = [r["viewer_peak_rss_kib"] for r in rs if r["viewer_peak_rss_kib"] is not None]
        pooled[kind] = {
            "rounds": len(rs),
            "ticks": int(sum(r["ticks"] for r in rs)),
            "compute_p50_us": float(np.percentile(compute, 50)),
            "compute_p99_us": float(np.percentile(compute, 99)),
            "compute_p999_us": float(np.percentile(compute, 99.9)),
            "wake_p50_us": float(np.percentile(wake, 50)),
            "wake_p99_us": float(np.percentile(wake, 99)),
            "deadline_misses": int(sum(r["deadline_misses"] for r in rs)),
            "ring_overflows": int(sum(r["ring_overflows"] for r in rs)),
            "stop_reasons": sorted({r["stop_reason"] for r in rs}),
            "feed_sent": int(sum(r["feed_sent"] for r in rs)),
            "feed_dropped": int(sum(r["feed_dropped"] for r in rs)),
            "viewer_peak_rss_mib": max(rss) / 1024 if rss else None,
            "messages_received": int(sum(r["messages_received"] for r in rs)),
        }
    return {"round_s": round_s, "rounds": rounds, "kinds": pooled}


def table(result: dict) -> list[str]:
    lines = [
        "| | ticks | compute p50 (us) | compute p99 (us) | compute p99.9 (us) | wake-up p50 (us) | "
        "wake-up p99 (us) | deadline misses | ring overflows | feed datagrams sent / dropped | "
        "live view peak RSS (MiB) | messages the client received | stop |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for kind, p in result["kinds"].items():
        rss = "-" if p["viewer_peak_rss_mib"] is None else f"{p['viewer_peak_rss_mib']:.0f}"
        feed = "-" if kind == "no viewer" else f"{p['feed_sent']} / {p['feed_dropped']}"
        received = "-" if kind == "no viewer" else str(p["messages_received"])
        lines.append(
            f"| {kind} | {p['ticks']} | {p['compute_p50_us']:.1f} | {p['compute_p99_us']:.1f} | "
            f"{p['compute_p999_us']:.1f} | {p['wake_p50_us']:.1f} | {p['wake_p99_us']:.1f} | "
            f"{p['deadline_misses']} | {p['ring_overflows']} | {feed} | {rss} | {received} | "
            f"{', '.join(p['stop_reasons'])} |"
        )
    return lines


def main() -> None:
    round_s = float(sys.argv[1]) if len(sys.argv) > 1 else ROUND_S
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else ROUNDS
    t0 = time.perf_counter()
    result = compare(round_s, rounds)
    print("\n".join(table(result)))
    print(f"\n{rounds} rounds of {round_s:g} s per kind, interleaved; {time.perf_counter() - t0:.0f} s")
    out = ROOT / "out" / "live_bench"
    out.mkdir(parents=True, exist_ok=True)
    (out / "live_view.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "python"))
    main()
