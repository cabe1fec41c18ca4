"""The ``sensaug`` command (``sensaug.cli:main``; also ``python -m sensaug``).

Each subcommand is a function here; ``sensaug --help`` lists them all (from
the parser itself, so the list cannot go stale) and ``sensaug CMD --help``
says what one does. Messages name the ``sensaug`` command. Ctrl-C on any
command is reported as an interruption with exit code 130; the rig reports
the results of the phases it completed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from sensaug import _core, experiment, presets
from sensaug._resources import package_version
from sensaug.config import ConfigError, ScenarioConfig
from sensaug.lqr import agent_gains

__all__ = ["main", "EXIT_INTERRUPTED"]

#: Exit code after Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130

_DESCRIPTION = """\
sensaug: human-robot sensory augmentation (partner identification with UKFs
and goal integration) on a simulated or a real 1-DoF rig.

Start with `sensaug demo` (the Hi5 experiment on the virtual rig) or
`sensaug paper` (the paper's headline numbers in simulation). Configurations
are TOML: `sensaug preset hi5 > hi5.toml`, edit, `sensaug check hi5.toml`,
`sensaug run hi5.toml`. `sensaug CMD --help` explains one command."""


def _table(headers: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(h.rjust(w) for h, w in zip(headers, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join([line, sep, *body])


def _bar(total: float, desc: str, unit: str, progress: bool | None):
    """A progress bar on stderr; ``progress`` None: only on a terminal (``sensaug._jupyter``)."""
    from sensaug._jupyter import bar

    return bar(total=total, desc=desc, unit=unit, progress=progress, leave=False)


def paper(seeds: int, out: Path | None, progress: bool | None = None) -> int:
    t_start = time.perf_counter()
    print("sensaug paper: the paper's Hi5 experiment and simulation, simulated, on the embedded defaults\n")

    hi5 = agent_gains(0.0035, 0.0, 1.0, 0.0)
    sim = agent_gains(6.0, 0.0, 20000.0, 2.0)
    print("Agent LQR gains (reduced 2-state CARE, docs/model.md)")
    print(
        _table(
            ["setting", "M", "Q_x", "Q_xdot", "k_pos", "k_vel"],
            [
                ["Hi5 robot", "0.0035", "1", "0", f"{hi5[0]:.4f}", f"{hi5[1]:.5f}"],
                ["simulation", "6", "20000", "2", f"{sim[0]:.4f}", f"{sim[1]:.4f}"],
            ],
        )
    )

    print(f"\nStage 1, Hi5: the virtual human's gains estimated, mean over the last 8 s ({seeds} seeds each)")
    rows = []
    trials = {}
    bar = _bar(len(presets.HI5_LHH_VALUES) * seeds, "stage 1", "trial", progress)
    for lhh in presets.HI5_LHH_VALUES:
        est = []
        for seed in range(seeds):
            tr = experiment.run(presets.hi5_experiment(lhh, seed=seed))
            trials[(lhh, seed)] = tr
            est.append(tr.gain_estimate())
            bar.update(1)
        est = np.array(est)
        worst = np.abs(est[:, 2] - lhh).max()
        rows.append(
            [
                f"{lhh:.1f}",
                f"{est[:, 0].mean():+.4f}",
                f"{est[:, 1].mean():+.4f}",
                f"{est[:, 2].mean():.4f}",
                f"{worst:.4f}",
            ]
        )
    bar.close()
    print(_table(["true L_hh", "est. L_hx", "est. L_hv", "est. L_hh", "max |est. L_hh - L_hh|"], rows))
    print("(L_hx, L_hh in N m/rad, L_hv in N m s/rad: the Hi5 presets' positions are in deg)")

    print("\nStage 2, Hi5: partner-trajectory RMSE (after 2 s), % of the 8 deg amplitude")
    rows = []
    for lhh in presets.HI5_LHH_VALUES[1:]:
        r = [trials[(lhh, s)].partner_target_rmse() / 8.0 * 100 for s in range(seeds)]
        rows.append([f"{lhh:.1f}", f"{np.mean(r):.2f}", f"{np.max(r):.2f}"])
    print(_table(["Lhh", "mean RMSE %", "max RMSE %"], rows))

    print("\nStage 3, Hi5 (Lhh = 2): RMSE of the robot's (x - tau) estimate, deg, mean over seeds")
    rows = []
    noises = (0.01, 0.1, 0.5, 1.0)
    bar = _bar(len(noises) * seeds + 1, "stage 3, simulation section", "trial", progress)
    for noise in noises:
        res = []
        for s in range(seeds):
            res.append(experiment.run(presets.hi5_experiment(2.0, seed=s, target_noise_std=noise)).integration_rmse())
            bar.update(1)
        own = np.mean([r["own"] for r in res])
        fused = np.mean([r["integrated"] for r in res])
        meas = np.mean([r["measured"] for r in res])
        rows.append([f"{noise:g}", f"{meas:.4f}", f"{own:.4f}", f"{fused:.4f}", f"{own / fused:.2f}x"])
    sim_trial = experiment.run(presets.simulation_section())
    bar.update(1)
    bar.close()
    print(_table(["target noise std", "measured", "own only", "integrated", "gain"], rows))

    m = sim_trial.phase_mask(0, last_s=8)
    robot_by_partner = [sim_trial[f][m].mean() for f in ("Lx_hat", "Lv_hat", "Lh_hat")]
    print("\nSimulation section (M = 6 kg, both agents LQR, each identifying the other)")
    print(
        _table(
            ["who estimates", "true gains", "estimated (last 8 s)"],
            [
                ["robot -> partner", _fmt(sim_trial.partner_gains), _fmt(sim_trial.gain_estimate())],
                ["partner -> robot", _fmt(sim_trial.robot_gains), _fmt(robot_by_partner)],
            ],
        )
    )
    if out is not None:
        from sensaug import plots

        out.mkdir(parents=True, exist_ok=True)
        written = plots.write_trial_plots(trials[(2.0, 0)], out, prefix="hi5_lhh2")
        written += plots.write_trial_plots(sim_trial, out, prefix="simulation")
        print(f"\nplots: {', '.join(str(p) for p in written)}")
    print(f"\ndone in {time.perf_counter() - t_start:.1f} s")
    return 0


def rig_demo(
    config: ScenarioConfig,
    out: Path,
    plots: bool,
    *,
    command: str = "demo",
    port: int | None = None,
    capture: str | None = "bus.log",
    progress: bool | None = None,
    feed: list[str] | None = None,
    live: int | None = None,
) -> int:
    from sensaug import rig

    t_start = time.perf_counter()
    phases = ", ".join(f"{p.kind} {p.duration_s:g} s" for p in config.phases)
    port = rig.bus_port(port)
    drive = rig.drive_profile_name(config.rig.drive)
    what = "the Hi5 experiment" if command == "demo" else "one trial"
    print(f"sensaug {command}: {what} on the virtual rig ({phases})")
    print(f"virtual {drive} drive (Python, python-can) <-> sensaug-rt (Rust, 1 kHz) over the loopback CAN bus")
    print(f"bus: sensaug_udp port {port} (watch it: python -m can.viewer -i sensaug_udp -c {port})")
    print(f"capture: {out / capture} ({rig.capture_format(out / capture)})\n" if capture else "capture: off\n", flush=True)
    also = None
    if plots:
        from sensaug.plots import RIG_PLOTS

        also = {f"plot {name}": out / name for name in RIG_PLOTS}
    feed = list(feed or [])
    viewer = None
    if live is not None:
        from sensaug.live import LiveProcess

        viewer = LiveProcess(port=live)
        feed.append(viewer.feed_address)
        print(f"live view: open {viewer.url} in Foxglove (Foxglove WebSocket; layout docs/live_layout.json)", flush=True)
    screen = None
    if config.display.enabled:
        from sensaug.display import DisplayProcess

        screen = DisplayProcess(config, workdir=out)
    try:
        run = rig.run_virtual_rig(config, out=out, port=port, capture=capture, progress=progress,
                                  also_written=also, feed=feed, display=screen)
    finally:
        if screen is not None:
            screen.close()
        if viewer is not None:
            viewer.stop()
    s = run.stats
    ran_s = float(run.log["t"][-1]) + config.plant.dt_s if len(run.log) else 0.0
    if run.interrupted:
        print(f"INTERRUPTED by the user (Ctrl-C) after {ran_s:.1f} s of {config.duration_s:g} s; "
              f"sensaug-rt stopped the drive: {s['stop_reason']}, {s['ticks']} ticks\n")
    elif run.stop_key is not None:
        print(f"STOPPED by the stop key ({run.stop_key['key']}) after {ran_s:.1f} s of {config.duration_s:g} s; "
              f"sensaug-rt stopped the drive: {s['stop_reason']}, {s['ticks']} ticks\n")
    else:
        print(f"sensaug-rt: {s['ticks']} ticks, stop: {s['stop_reason']}, exit {run.returncode}; "
              f"virtual drive exit {run.drive_returncode}\n")
    done = run.completed_phases()
    why = ("interrupted by the user" if run.interrupted
           else "stopped by the stop key" if run.stop_key is not None else f"the run stopped: {s['stop_reason']}")

    def cut(kind: str) -> str:
        m = run.log["phase"] == run.log.phase_code(kind)
        if not m.any():
            return f"not reached ({why})"
        return f"cut off after {m.sum() * config.plant.dt_s:.1f} s ({why}); no result from a partial phase"

    # A person has no true gain and no true target: their estimates, the
    # estimates' variances and the target the person was shown, never an
    # error against a "truth" (docs/person.md).
    person = not config.rig.virtual_human
    if person:
        shown = "shown on the display" if config.display.enabled else "NOT shown to the person: the display is off"
        print(f"A person at the handle (rig.virtual_human = false): no true partner gain or target; "
              f"the partner's target tau_h {shown}\n")
    if "gains" in done:
        window = run.gain_window_s()
        print(f"Stage 1: partner gains (mean over the last {window:g} s of the gain phase)")
        units = [run.log.units.get(c, "") for c in ("Lhx_hat", "Lhv_hat", "Lhh_hat")]
        if person:
            m = run.phase_mask("gains", last_s=window)
            sd = [float(np.sqrt(np.mean(run.log[c][m]))) for c in ("Lhx_var", "Lhv_var", "Lhh_var")]
            print(_table(["gain", "unit", "estimated", "posterior std"], [
                [name, u, f"{e:.4f}", f"{v:.4f}"]
                for name, u, e, v in zip(experiment.GAIN_SYMBOLS, units, run.gain_estimate(), sd)
            ]))
        else:
            true = np.array(s["partner_gains_true"])
            print(_table(["gain", "unit", "true", "estimated", "error"], [
                [name, u, f"{t:.4f}", f"{e:.4f}", f"{e - t:+.4f}"]
                for name, u, t, e in zip(experiment.GAIN_SYMBOLS, units, true, run.gain_estimate())
            ]))
    else:
        print(f"Stage 1: {cut('gains')}")
    if "trajectory" in done:
        amp = max(abs(sh.amplitude) for sh in config.phases[1].partner_target if hasattr(sh, "amplitude")) if len(config.phases) > 1 else 1.0
        rmse = run.partner_target_rmse()
        unit = run.log.units.get("tau_h_hat", "")
        if not person:
            print(f"\nStage 2: partner-target RMSE {rmse:.4f} {unit} ({100 * rmse / amp:.2f}% of the {amp:g} {unit} amplitude)")
        elif config.display.enabled:
            print(f"\nStage 2: RMSE of the partner-target estimate against the target shown to the person "
                  f"{rmse:.4f} {unit} ({100 * rmse / amp:.2f}% of its {amp:g} {unit} amplitude)")
        else:
            m = run.phase_mask("trajectory")
            print(f"\nStage 2: partner-target estimate, posterior std {np.sqrt(np.mean(run.log['tau_h_var'][m])):.4f} "
                  f"{unit} (mean over the phase); no target was shown, so no error is computed")
    else:
        print(f"\nStage 2: {cut('trajectory')}")
    if "integration" in done:
        r = run.integration_rmse()
        noise = config.phases[-1].target_noise_std
        unit = run.log.units.get("e_meas", "")
        print(f"\nStage 3: RMSE of the robot's estimate of x - tau ({unit}), target-view noise std {noise:g} {unit}")
        print(_integration_table(r))
    else:
        print(f"\nStage 3: {cut('integration')}")
    print("\nLoop statistics (this machine, this run; no deadline is asserted)")
    rows = [[name, f"{h['p50_us']:.0f}", f"{h['p99_us']:.0f}", f"{h['p999_us']:.0f}", f"{h['max_us']:.0f}"]
            for name, h in (("wake-up latency (us)", s["wake_latency"]), ("tick compute (us)", s["compute"]))]
    print(_table(["", "p50", "p99", "p99.9", "max"], rows))
    can = s["can"]
    print(f"deadline misses {s['deadline_misses']}, CAN send/recv/decode errors "
          f"{can['send_errors']}/{can['recv_errors']}/{can['decode_errors']}, missing feedback {can['missing_feedback']}, "
          f"ring overflows {s['ring_overflows']}, records {s['records_written']}, clamped {s['torque_clamped']}")
    print(f"real-time settings: {'; '.join(s['realtime'])}")
    if run.capture is not None:
        c = run.capture
        print(f"bus capture: {c.frames} frames, {c.dropped_kernel} dropped by the kernel, "
              f"{c.cpu_s:.2f} s CPU in the launcher's capture thread" + (f", ERROR {c.error}" if c.error else ""))
    if run.display is not None:
        dsp = run.display
        lat = (f"tick-to-swap latency p50 {dsp['latency_p50_ms']:.1f} ms, p99 {dsp['latency_p99_ms']:.1f} ms"
               if "latency_p50_ms" in dsp else "tick-to-swap latency unknown")
        print(f"display: {dsp['frames']} frames, {dsp['dropped']} dropped, {lat}"
              + (f"; {dsp['event']}" + (", the loop was stopped" if dsp["stopped_loop"] else "") if dsp["event"] else ""))
    print(f"\nlog: {out / 'rig_log.csv'} (sensaug.load_log), stats: {out / 'rig_stats.json'}")
    if plots and len(done) < 3:
        print(f"plots: skipped, the run did not complete every phase ({why})")
    elif plots:
        from sensaug import plots as pl

        written = pl.write_rig_plots(run, out)
        print(f"plots: {', '.join(str(p) for p in written)}")
        run.write_readme(out, {Path(p).name: f"plot of the run: {Path(p).stem.replace('_', ' ')} (PNG)" for p in written})
    print(f"what is in {out}: {out / 'README.txt'}")
    print(f"\ndone in {time.perf_counter() - t_start:.1f} s")
    if run.interrupted:
        return EXIT_INTERRUPTED
    return 0 if run.returncode == 0 else 1


def _integration_table(r: dict[str, float]) -> str:
    """The goal-integration RMSEs (``Trial.integration_rmse``) as one table row."""
    return _table(["measured", "own sensing only", "with goal integration", "improvement"], [
        [f"{r['measured']:.4f}", f"{r['own']:.4f}", f"{r['integrated']:.4f}", f"{r['own'] / r['integrated']:.2f}x"]
    ])


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.3f}" for x in v) + "]"


def _budget(gb: float | None) -> int | None:
    """``--max-memory`` in bytes (None: the default, half the available memory)."""
    if gb is None:
        return None
    if not gb > 0:
        raise ValueError(f"--max-memory: must be > 0 GB, got {gb:g}")
    return int(gb * 1e9)


def run_config(path: Path, out: Path | None, max_memory_gb: float | None = None) -> int:
    cfg = ScenarioConfig.from_toml(path)
    trial = experiment.run(cfg, memory_budget=_budget(max_memory_gb))
    out = trial.save(out or path.with_suffix(".csv"))
    print(f"sensaug run: {path}, {len(trial)} ticks ({trial.config.duration_s:g} s)\n")
    table = trial.metrics()
    print("The paper's metrics (Trial.metrics())")
    print(table.drop(columns="kind").to_string(index=False, float_format=lambda v: f"{v:.4f}", na_rep=""))
    print(f"\nlog: {out} (sensaug.load_log)")
    return 0


def _grid_values(text: str) -> list[object]:
    """``0,0.5,true`` -> [0, 0.5, True]; ``[1e-2,1e-3],[1e-3,1e-4]`` -> two
    lists (a list field's values); ``udp:1,udp:2`` -> strings: the text is
    read as the items of a TOML array, else split at commas (bare strings)."""
    import tomllib

    try:
        return list(tomllib.loads(f"v = [{text}]")["v"])
    except tomllib.TOMLDecodeError:
        pass
    out: list[object] = []
    for item in text.split(","):
        item = item.strip()
        try:
            out.append(tomllib.loads(f"v = {item}")["v"])
        except tomllib.TOMLDecodeError:
            out.append(item)
    return out


def write_results(df, out: Path, sweep_meta: dict) -> tuple[Path, Path]:
    """A sweep's table as ``results.csv`` and, beside it, ``results.parquet``
    (pyarrow: typed columns, opens fast in pandas and DuckDB; the grid and
    seeds in its schema metadata under ``sensaug``). A swept column mixing
    kinds (numbers and text) is written as text in the Parquet file."""

    import pyarrow as pa
    import pyarrow.parquet as pq

    csv, parquet = out / "results.csv", out / "results.parquet"
    df.to_csv(csv, index=False)
    typed = df.copy()
    for name in typed.columns[typed.dtypes == object]:
        if len({type(v) for v in typed[name]}) > 1:
            typed[name] = typed[name].astype(str)
    table = pa.Table.from_pandas(typed, preserve_index=False)
    meta = {**(table.schema.metadata or {}), b"sensaug": json.dumps({**sweep_meta, "version": package_version()}).encode()}
    pq.write_table(table.replace_schema_metadata(meta), parquet)
    return csv, parquet


def sweep_command(
    config: Path,
    grid_args: list[str],
    seeds: int,
    workers: int | None,
    out: Path,
    progress: bool | None = None,
    max_memory_gb: float | None = None,
) -> int:
    """``sensaug sweep``: results.csv, the base configuration and the grid in ``out``."""

    from sensaug.sweep import sweep

    if seeds < 1:
        raise ValueError("--seeds: must be >= 1")
    grid: dict[str, list[object]] = {}
    for g in grid_args:
        path, sep, values = g.partition("=")
        if not sep or not values:
            raise ValueError(f"--grid {g!r}: write PATH=V1,V2,... (e.g. partner.gains.lhh=0,1,2)")
        grid[path.strip()] = _grid_values(values)
    base = ScenarioConfig.from_toml(config)
    t0 = time.perf_counter()
    df = sweep(base, grid, seeds=range(seeds), progress=progress, workers=workers, memory_budget=_budget(max_memory_gb))
    elapsed = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    write_results(df, out, {"grid": grid, "seeds": list(range(seeds))})
    base.to_toml(out / "config.toml")
    (out / "grid.json").write_text(json.dumps({"grid": grid, "seeds": list(range(seeds))}, indent=1) + "\n")
    (out / "README.md").write_text(
        "# sensaug sweep\n\n"
        f"`results.csv`: {len(df)} trials, one row each (swept values, seed, headline metrics);\n"
        "`results.parquet`: the same table as Parquet (typed columns; pandas.read_parquet, DuckDB);\n"
        "`config.toml`: the base configuration; `grid.json`: the grid and the seeds\n"
        "(each seed sets the seed fields the grid does not: world.seed = seed,\n"
        "robot.seed = seed + 1000003, partner.integration.seed = seed + 2000003).\n"
    )
    keys = list(grid)
    metrics_cols = [c for c in df.columns if c not in (*keys, "seed")]
    print(f"sensaug sweep: {config}, {len(df)} trials; mean over seeds 0..{seeds - 1}"
          + (f" per value of {', '.join(keys)}" if keys else ""))
    if keys:
        # A list-valued field (robot.stage1.Q=[...]) groups by its text.
        view = df.assign(**{k: df[k].map(str) for k in keys if df[k].map(lambda v: isinstance(v, list)).any()})
        print(view.groupby(keys)[metrics_cols].mean().to_string())
    else:
        print(df[metrics_cols].agg(["mean", "std"]).T.to_string())
    print(f"\n{len(df)} trials in {elapsed:.1f} s; results -> {out}")
    return 0


def check(path: str) -> int:
    """``valid`` and 0 for a good file; the first bad field on stderr and 2
    otherwise (the file itself is named when its syntax is bad). A session
    plan's blocks are expanded and checked, as ``sensaug-rt --check`` does
    (one implementation: ``sensaug_config::person::check_conditions``)."""
    try:
        _core.Config.from_file(path, check_outputs=True)
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    print("valid")
    return 0


def docs(page: str | None) -> int:
    """``sensaug docs``: the pages and their titles; ``sensaug docs NAME``: one page's text."""
    from sensaug._resources import docs_dir

    folder = docs_dir()
    pages = {p.stem: p for p in sorted(folder.glob("*.md"))}
    if page is None:
        print(f"The docs pages ({folder}); `sensaug docs NAME` prints one:")
        for name, path in pages.items():
            title = path.read_text().split("\n", 1)[0].lstrip("# ")
            print(f"  {name:14s} {title}")
        return 0
    name = Path(page).stem  # "logs", "logs.md" and "docs/logs.md" all work
    if name not in pages:
        print(f"error: docs: no page {page!r}; the pages are {', '.join(pages)}", file=sys.stderr)
        return 2
    sys.stdout.write(pages[name].read_text())
    return 0


def _drive_profiles() -> list[str]:
    """The ``[rig] drive`` profiles: the schema's enum."""
    from sensaug.config import schema

    return [choice["const"] for choice in schema()["$defs"]["DriveProfile"]["oneOf"]]


def _rig_options(p: argparse.ArgumentParser) -> None:
    """``demo``'s and ``rig``'s drive profile, bus, capture and progress options."""
    p.add_argument("--drive", choices=_drive_profiles(), default=None,
                   help="drive profile (sets [rig] drive; default: the configuration's, hi5 unless it says otherwise)")
    p.add_argument("--port", type=int, default=None, help="loopback CAN bus UDP port 1..65535 (default: a free one)")
    p.add_argument("--capture", default="bus.log", metavar="NAME",
                   help="bus capture file in --out; the suffix picks the format: .log candump -l (default bus.log), .blf")
    p.add_argument("--no-capture", action="store_true", help="do not record the bus")
    p.add_argument("--quiet", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    p.add_argument("--feed", action="append", default=[], metavar="127.0.0.1:PORT",
                   help="send the run's rows live to this loopback UDP address (repeatable; docs/live.md)")
    p.add_argument("--live", nargs="?", const=8765, type=int, default=None, metavar="PORT",
                   help="live view of the run in Foxglove: ws://127.0.0.1:PORT (default 8765; docs/live.md)")


def _progress(args: argparse.Namespace) -> bool | None:
    """Progress bars: off with --quiet, else tqdm's default (only on a terminal)."""
    return False if args.quiet else None


def _with_drive(cfg: ScenarioConfig, args: argparse.Namespace) -> ScenarioConfig:
    """``cfg`` with ``--drive``'s profile, if given."""
    if args.drive is not None:
        cfg.rig.drive = args.drive
    return cfg


def _rig_kwargs(args: argparse.Namespace) -> dict:
    return {"port": args.port, "capture": None if args.no_capture else args.capture, "progress": _progress(args),
            "feed": args.feed, "live": args.live}


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """argparse's, with the help column past the longest command's name:
    argparse measures the commands at the group's indent but prints them 2
    further in, so a name of 8 or more letters pushed its help to the next
    line."""

    def add_argument(self, action: argparse.Action) -> None:
        super().add_argument(action)
        if isinstance(action, argparse._SubParsersAction) and action.choices:
            longest = max(len(name) for name in action.choices)
            self._action_max_length = max(self._action_max_length, longest + self._current_indent + 2)


def build_parser() -> argparse.ArgumentParser:
    """The ``sensaug`` command's parser: every subcommand, its options and help."""
    parser = argparse.ArgumentParser(
        prog="sensaug", description=_DESCRIPTION, formatter_class=_HelpFormatter,
        epilog="Documentation: `sensaug docs` lists the pages that come with the package (messages name them "
               "docs/NAME.md; `sensaug docs NAME` prints one); in a checkout, bash scripts/build-docs.sh builds "
               "them with the API reference into a site.",
    )
    parser.add_argument("--version", action="version", version=f"sensaug {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, title="commands", metavar="COMMAND")
    d = sub.add_parser("demo", help="the Hi5 experiment end to end on the virtual rig")
    d.add_argument("--config", type=Path, default=None, help="TOML (default: the embedded hi5-rig preset)")
    d.add_argument("--out", type=Path, default=Path("out"), help="folder for log, stats, plots (default ./out)")
    d.add_argument("--no-plots", action="store_true", help="do not write plots")
    _rig_options(d)
    pp = sub.add_parser("paper", help="reproduce the paper's headline numbers in simulation")
    pp.add_argument("--seeds", type=int, default=3, help="trials per setting (default 3)")
    pp.add_argument("--plots", type=Path, default=Path("out"), help="folder for plots (default ./out)")
    pp.add_argument("--no-plots", action="store_true", help="do not write plots")
    pp.add_argument("--quiet", action="store_true", help="no progress bars (they show only on a terminal anyway)")
    rg = sub.add_parser("rig", help="run one trial on the virtual rig")
    rg.add_argument("config", type=Path)
    rg.add_argument("--out", type=Path, default=Path("out"))
    _rig_options(rg)
    r = sub.add_parser("run", help="run one trial from a TOML configuration")
    r.add_argument("config", type=Path)
    r.add_argument("--out", type=Path, default=None, help="log file (.csv); default next to the config")
    r.add_argument("--max-memory", type=float, default=None, metavar="GB",
                   help="the most memory the trial's log may take (default: half of the available memory)")
    p = sub.add_parser("preset", help="print a preset configuration as TOML")
    p.add_argument("name", choices=["hi5", "hi5-rig", "simulation"])
    sw = sub.add_parser("sweep", help="run a configuration over a grid of settings and seeds")
    sw.add_argument("config", type=Path, help="the base configuration (TOML)")
    sw.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="PATH=V1,V2,...",
        help="a dotted path of the schema and its values, e.g. partner.gains.lhh=0,1,2 (repeatable)",
    )
    sw.add_argument("--seeds", type=int, default=12, help="seeds 0..N-1 per grid point (default 12)")
    sw.add_argument("--workers", type=int, default=None, help="threads (default: one per core)")
    sw.add_argument("--max-memory", type=float, default=None, metavar="GB",
                    help="the most memory the logs of the trials running at once may take "
                         "(default: half of the available memory); fewer run at once")
    sw.add_argument("--out", type=Path, default=Path("out/sweep"), help="output folder (default out/sweep)")
    sw.add_argument("--quiet", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    fg = sub.add_parser("figures", help="every computational figure of the paper (PNG, PDF) and REPORT.md")
    fg.add_argument("--out", type=Path, default=Path("out/figures"), help="output folder (default out/figures)")
    fg.add_argument("--quick", action="store_true", help="reduced budget of trials and seeds (the tests' report)")
    c = sub.add_parser("check", help="validate a configuration file exactly as sensaug-rt --check does")
    c.add_argument("config", help="TOML (or .json) configuration file")
    sub.add_parser("schema", help="print the configuration's JSON Schema (fields, units, defaults, bounds)")
    lv = sub.add_parser("live", help="live view of rig runs in Foxglove, fed by sensaug-rt --feed (docs/live.md)")
    lv.add_argument("--feed-port", type=int, default=9870, help="loopback UDP port the feed is read on (default 9870)")
    lv.add_argument("--port", type=int, default=8765, help="Foxglove WebSocket port (default 8765; 0: a free one)")
    lv.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                    help="messages per topic per second; each keeps its bin's min and max (default 100)")
    lv.add_argument("--lan", action="store_true",
                    help="listen on every interface (the lab network), not only 127.0.0.1")
    lv.add_argument("--write-layout", type=Path, default=None, metavar="FILE",
                    help="write the live view's Foxglove layout (JSON) and exit")
    ex = sub.add_parser("export", help="a log as MCAP for Foxglove and PlotJuggler (docs/live.md)")
    ex.add_argument("log", type=Path, help="a log file (.csv): simulated trial, rig run or session trial")
    ex.add_argument("--to", choices=["mcap"], required=True, help="the format (mcap: Foxglove's own format)")
    ex.add_argument("--out", type=Path, default=None, help="output file (default: the log's path with .mcap)")
    se = sub.add_parser("session", help="run a participant's blocks of trials from a plan (docs/person.md)")
    se.add_argument("plan", type=Path, help="the plan: a trial configuration with a [session] table (TOML)")
    se.add_argument("--participant", required=True, help="participant id with a number (P01): the folder and the block order")
    se.add_argument("--resume", action="store_true", help="continue the participant's session at its first unfinished trial")
    se.add_argument("--out", type=Path, default=Path("sessions"), help="folder of participant folders (default ./sessions)")
    se.add_argument("--no-display", action="store_true", help="no display (only with the virtual human)")
    se.add_argument("--simulate", action="store_true",
                    help="simulate every trial (the virtual human; a rehearsal of the plan, minutes not hours)")
    sub.add_parser("display", add_help=False, help="the participant's display alone (sensaug display --help)")
    dr = sub.add_parser("doctor", help="check this host for a rig run: CAN interface, real-time set-up, drive "
                                       "(docs/hardware.md; exit 1 when a check fails)")
    dr.add_argument("config", nargs="?", type=Path, default=None,
                    help="the rig configuration (default: the hi5-rig preset)")
    dr.add_argument("--can", default=None, help="the CAN link to check instead of rig.can (socketcan:can0, udp:PORT)")
    dr.add_argument("--bitrate", type=int, default=1_000_000, help="the bitrate expected, bit/s (default 1000000)")
    dr.add_argument("--sdo", action="store_true",
                    help="also ask the drive at rig.node_id (CiA 402: an SDO read of 0x1000; sends one frame)")
    cal = sub.add_parser(
        "calibrate", help="identify the handle's inertia, damping and Coulomb friction by a bounded excitation on "
                          "the rig; write the configuration fragment that compensates them (docs/hardware.md)")
    cal.add_argument("config", nargs="?", type=Path, default=None,
                     help="the rig configuration: its drive, bus, torque limit and range bound the excitation "
                          "(default: the hi5-rig preset)")
    cal.add_argument("--out", type=Path, default=Path("out/calibration"),
                     help="folder for the run, calibration.toml and calibrated_config.toml (default out/calibration)")
    cal.add_argument("--duration", type=float, default=20.0, metavar="S", help="excitation length, s (default 20)")
    cal.add_argument("--seed", type=int, default=0, help="world.seed of the excitation run (default 0)")
    cal.add_argument("--virtual-handle", nargs=3, type=float, default=None, metavar=("M", "C", "FC"),
                     help="the handle the virtual drive simulates: inertia kg m^2, viscous N m s/rad, Coulomb N m; "
                          "given to the drive process only (default: the drive's own, 0.0035 0 0)")
    cal.add_argument("--log", type=Path, default=None, metavar="RIG_LOG",
                     help="identify from this rig log instead of running (a real rig's excitation run)")
    cal.add_argument("--write-excitation", type=Path, default=None, metavar="FILE",
                     help="write the excitation run's configuration (for sensaug-rt on a real rig) and exit")
    cal.add_argument("--port", type=int, default=None, help="loopback CAN bus UDP port (default: a free one)")
    cal.add_argument("--quiet", action="store_true", help="no progress bar")
    dc = sub.add_parser("docs", help="list the documentation pages, or print one (docs/NAME.md)")
    dc.add_argument("page", nargs="?", default=None, help="a page's name, e.g. logs or docs/logs.md")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["display"]:
        from sensaug import display

        return display.main(argv[1:])
    args = parser.parse_args(argv)
    if args.command == "check":
        return check(args.config)
    if args.command == "schema":
        print(_core.config_schema())
        return 0
    if args.command == "docs":
        return docs(args.page)
    if args.command == "doctor":
        from sensaug import doctor

        return doctor.main(args.config, args.can, args.bitrate, args.sdo)
    try:
        if args.command == "demo":
            cfg = ScenarioConfig.from_toml(args.config) if args.config else presets.hi5_rig()
            return rig_demo(_with_drive(cfg, args), args.out, not args.no_plots, **_rig_kwargs(args))
        if args.command == "paper":
            if args.seeds < 1:
                parser.error("--seeds: must be >= 1")
            return paper(args.seeds, None if args.no_plots else args.plots, _progress(args))
        if args.command == "run":
            return run_config(args.config, args.out, args.max_memory)
        if args.command == "sweep":
            return sweep_command(
                args.config, args.grid, args.seeds, args.workers, args.out, _progress(args), args.max_memory
            )
        if args.command == "live":
            from sensaug import live

            if args.write_layout is not None:
                args.write_layout.write_text(json.dumps(json.loads(live.layout().to_json()), indent=1) + "\n")
                print(f"layout -> {args.write_layout} (Foxglove: Layout -> Import from file)")
                return 0
            return live.serve(args.feed_port, "0.0.0.0" if args.lan else "127.0.0.1", args.port, args.rate)
        if args.command == "export":
            from sensaug.export import to_mcap

            written = to_mcap(args.log, args.out or args.log.with_suffix(".mcap"))
            print(f"{args.log} -> {written} (open it in Foxglove or PlotJuggler: docs/live.md)")
            return 0
        if args.command == "figures":
            import matplotlib

            matplotlib.use("Agg")
            from sensaug import figures

            t0 = time.perf_counter()
            written = figures.write_all(args.out, quick=args.quick)
            print(f"{len(written)} files in {args.out} ({time.perf_counter() - t0:.1f} s); see {args.out / 'REPORT.md'}")
            return 0
        if args.command == "rig":
            cfg = _with_drive(ScenarioConfig.from_toml(args.config), args)
            return rig_demo(cfg, args.out, True, command="rig", **_rig_kwargs(args))
        if args.command == "calibrate":
            from sensaug import calibrate

            if args.duration <= 0:
                parser.error("--duration: must be > 0 s")
            return calibrate.command(
                args.config, out=args.out, duration_s=args.duration, seed=args.seed, log_path=args.log,
                write_excitation=args.write_excitation,
                virtual_handle=None if args.virtual_handle is None else tuple(args.virtual_handle),
                port=args.port, progress=_progress(args),
            )
        if args.command == "session":
            from sensaug.session import load_session, run_session

            folder = run_session(args.plan, args.participant, out=args.out, resume=args.resume,
                                 display=False if args.no_display or args.simulate else None, simulate=args.simulate)
            loaded = load_session(folder)
            written = loaded.plot_blocks(folder / "figures")
            print(loaded.summary().to_string(float_format=lambda v: f"{v:.4f}"))
            print(f"session: {folder} (manifest.csv; sensaug.load_session); figures: {', '.join(str(p) for p in written)}")
            return 0
        cfg = {"hi5": presets.hi5_experiment, "hi5-rig": presets.hi5_rig, "simulation": presets.simulation_section}[args.name]()
        sys.stdout.write(cfg.to_toml())
        return 0
    except (ValueError, FileNotFoundError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\nsensaug {args.command}: interrupted by the user (Ctrl-C); results are incomplete", file=sys.stderr)
        return EXIT_INTERRUPTED
