"""Sessions of trials: a plan (a trial configuration with a ``[session]``
table: blocks, each a condition run N times) run for one participant into
one folder, resumable after a crash (docs/person.md).

``sensaug session PLAN.toml --participant P03 [--resume]`` or
:func:`run_session`; :func:`load_session` reads a participant's folder back.

The folder ``<out>/<participant>/``:

* ``plan.toml`` (the plan as given) and ``session.json`` (participant,
  number, block order and how it was drawn);
* ``manifest.csv``: one row per trial attempt, appended and fsync'ed as
  each attempt ends (block, trial, practice round, attempt, condition, seed,
  start time, stop reason, headline metrics);
* ``trials/<trial>_<block>_<k>_a<attempt>/``: the attempt's files
  (``rig_config.toml``, ``rig_log.csv``, ``rig_stats.json``, ``bus.log``,
  ``display_log.csv``; ``trial_log.csv`` simulated); never written again
  once its manifest row exists;
* ``questionnaire.csv``: the answers after each block.

Resume: the trials with a finished attempt are skipped; an attempt folder
without a manifest row (the session died during it) gets a row with stop
reason ``interrupted`` and its trial runs again as a new attempt.
"""

from __future__ import annotations

import copy
import csv
import json
import math
import os
import re
import shutil
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from sensaug.config import ConfigError, ScenarioConfig
from sensaug.sweep import SEED_FIELDS, set_path

__all__ = ["Session", "SessionTrial", "block_order", "expand", "latin_square", "load_session", "run_session"]

#: Manifest columns (metrics follow, named as in ``sensaug sweep``).
MANIFEST_FIELDS = (
    "trial", "block", "index", "practice", "round", "attempt", "condition", "seed", "start_utc", "folder",
    "stop_reason", "finished", "Lhx_hat", "Lhv_hat", "Lhh_hat", "Lhh_var", "tau_h_rmse", "rmse_measured",
    "rmse_own", "rmse_integrated", "estimator_errors", "truth_Lhh", "display_frames", "display_dropped", "display_latency_p50_ms",
    "display_latency_p99_ms", "display_event",
)
#: Stop reasons of a finished trial.
FINISHED = ("completed",)
#: Unattended (virtual human), an aborted trial is re-run at most this often.
MAX_ATTEMPTS = 3


def latin_square(n: int) -> list[list[int]]:
    """A balanced Latin square (Williams design) over ``n`` conditions: each
    condition once per row and column, and each ordered pair of neighbours
    once (n even) or twice over the 2n rows (n odd: the rows and their
    mirror images)."""
    first = [0]
    lo, hi = 1, n - 1
    for j in range(1, n):
        if j % 2:
            first.append(lo)
            lo += 1
        else:
            first.append(hi)
            hi -= 1
    rows = [[(c + r) % n for c in first] for r in range(n)]
    if n % 2:
        rows += [row[::-1] for row in rows]
    return rows


def participant_number(participant: str) -> int:
    """The number in a participant id (``P07`` -> 7): the Latin square's row."""
    digits = re.findall(r"\d+", participant)
    if not digits:
        raise ValueError(f"--participant: {participant!r} has no number; use ids like P01, P02 (the number picks the block order)")
    return int(digits[-1])


def block_order(plan: ScenarioConfig, participant: str) -> tuple[list[int], str]:
    """Block indices in the order this participant runs them (practice
    blocks first, as listed) and how that order was drawn."""
    s = plan.session
    practice = [i for i, b in enumerate(s.blocks) if b.practice]
    main = [i for i, b in enumerate(s.blocks) if not b.practice]
    order = s.order.value if hasattr(s.order, "value") else s.order
    n = participant_number(participant)
    if order == "latin_square":
        rows = latin_square(len(main))
        row = n % len(rows)
        return practice + [main[j] for j in rows[row]], f"latin_square row {row} of {len(rows)} (participant number {n})"
    if order == "shuffle":
        rng = np.random.default_rng([int(s.seed), n])
        return practice + [main[j] for j in rng.permutation(len(main))], f"shuffle seeded [session.seed={s.seed}, {n}]"
    return practice + main, "fixed"


@dataclass
class SessionTrial:
    """One trial of the participant's list."""

    trial: int
    block: str
    index: int
    practice: bool
    config: ScenarioConfig
    seed: int
    condition: dict[str, Any] = field(default_factory=dict)


def _block_config(plan: ScenarioConfig, b_index: int, seed: int) -> ScenarioConfig:
    block = plan.session.blocks[b_index]
    cfg = copy.deepcopy(plan)
    cfg.session = None
    if block.phases:
        cfg.phases = [cfg.phases[i] for i in block.phases]
    for path, value in (block.set or {}).items():
        set_path(cfg, path, value)
    for path, offset in SEED_FIELDS.items():
        if path in (block.set or {}):
            continue
        try:
            set_path(cfg, path, seed + offset)
        except ConfigError:
            pass  # partner.integration absent: no seed to set
    return cfg


def expand(plan: ScenarioConfig, participant: str) -> list[SessionTrial]:
    """The participant's trial list, each trial's configuration validated.

    Raises:
        ConfigError: ``session.blocks[i].set."<path>": ...`` naming the block
            and the field a condition sets wrongly.
    """
    if plan.session is None:
        raise ConfigError("session", "the plan has no [session] table; add [[session.blocks]] (docs/person.md)")
    order, _ = block_order(plan, participant)
    out: list[SessionTrial] = []
    for b in order:
        block = plan.session.blocks[b]
        for k in range(block.trials):
            seed = int(plan.session.seed) + k
            try:
                cfg = _block_config(plan, b, seed)
                cfg.validate()
            except ConfigError as e:
                raise ConfigError(f"session.blocks[{b}].set", str(e)) from None
            out.append(SessionTrial(len(out), block.name, k, bool(block.practice), cfg, seed, dict(block.set or {})))
    return out


# --- running ------------------------------------------------------------------

def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _fsync_append(path: Path, row: dict) -> None:
    new = not path.exists()
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=MANIFEST_FIELDS)
        if new:
            w.writeheader()
        w.writerow({k: ("" if v is None else v) for k, v in row.items()})
        f.flush()
        os.fsync(f.fileno())


def _read_manifest(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _metrics_rig(run) -> dict:
    """Headline metrics of a rig run: the estimates (never a 'truth' with a person)."""
    from sensaug import metrics

    out: dict[str, Any] = {}
    log = run.log
    for kind in ("gains", "trajectory", "integration"):
        if not (log["phase"] == log.phase_code(kind)).any():
            continue
        if kind == "gains":
            g = run.gain_estimate()
            m = run.phase_mask("gains", last_s=run.config.robot.gain_window_s)
            var = log["Lhh_var"][m]
            out.update(Lhx_hat=g[0], Lhv_hat=g[1], Lhh_hat=g[2], Lhh_var=float(var.mean()) if len(var) else math.nan)
        elif kind == "trajectory":
            out["tau_h_rmse"] = run.partner_target_rmse(skip_s=min(2.0, _phase_s(run.config, kind) / 2))
        else:
            r = metrics.integration_rmse(log, run.phase_mask("integration", skip_s=min(2.0, _phase_s(run.config, kind) / 2)))
            out.update(rmse_measured=r["measured"], rmse_own=r["own"], rmse_integrated=r["integrated"])
    return out


def _phase_s(cfg: ScenarioConfig, kind: str) -> float:
    return next(p.duration_s for p in cfg.phases if (p.kind.value if hasattr(p.kind, "value") else p.kind) == kind)


class Session:
    """A participant's session folder and its state (see the module doc)."""

    def __init__(self, plan_path: str | Path, participant: str, out: str | Path) -> None:
        self.plan_path = Path(plan_path)
        self.plan = ScenarioConfig.from_toml(self.plan_path)
        self.participant = participant
        self.folder = Path(out) / participant
        self.trials = expand(self.plan, participant)
        self.manifest = self.folder / "manifest.csv"
        self.simulated = False

    @property
    def trials_run(self) -> str:
        """How this session's trials run: "simulated" or on the rig."""
        return "simulated" if self.simulated or not self.plan.session.rig else "virtual rig (sensaug-rt)"

    def create(self, resume: bool) -> None:
        if self.manifest.exists() or (self.folder / "session.json").exists():
            if not resume:
                raise ValueError(f"--participant: {self.folder} already has a session; add --resume to continue it, "
                                 "or give another participant or --out")
            saved = json.loads((self.folder / "session.json").read_text())
            if saved["plan_sha"] != _sha(self.plan_path):
                raise ValueError(f"--resume: {self.plan_path} differs from the plan {self.folder / 'plan.toml'} "
                                 "the session started with; resume with that plan")
            return
        if resume:
            raise ValueError(f"--resume: {self.folder} has no session to resume; drop --resume to start one")
        (self.folder / "trials").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(self.plan_path, self.folder / "plan.toml")
        order, how = block_order(self.plan, self.participant)
        info = {
            "participant": self.participant, "participant_number": participant_number(self.participant),
            "blocks": [self.plan.session.blocks[i].name for i in order], "order": how,
            "plan_sha": _sha(self.plan_path), "created_utc": _now(),
            "trials_run": self.trials_run,
            "trials": [{"trial": t.trial, "block": t.block, "index": t.index, "practice": t.practice,
                        "seed": t.seed, "condition": t.condition} for t in self.trials],
        }
        (self.folder / "session.json").write_text(json.dumps(info, indent=1) + "\n")

    def rows(self) -> list[dict]:
        return _read_manifest(self.manifest)

    def recover(self) -> list[str]:
        """Attempt folders without a manifest row (the session died during
        them) get a row, stop reason ``interrupted``; their names."""
        known = {r["folder"] for r in self.rows()}
        lost = []
        for d in sorted((self.folder / "trials").iterdir()):
            rel = f"trials/{d.name}"
            if rel in known:
                continue
            m = re.match(r"(\d+)_(.+)_(\d+)_r(\d+)_a(\d+)$", d.name)
            if not m:
                continue
            t = self.trials[int(m.group(1))]
            _fsync_append(self.manifest, {
                "trial": t.trial, "block": t.block, "index": t.index, "practice": int(t.practice),
                "round": int(m.group(4)), "attempt": int(m.group(5)), "condition": json.dumps(t.condition),
                "seed": t.seed, "start_utc": "", "folder": rel, "stop_reason": "interrupted", "finished": 0,
            })
            lost.append(d.name)
        return lost


def _sha(path: Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class Console:
    """The experimenter's and participant's side when nobody is attached
    (virtual human): prompts are printed, keys answered by a script."""

    def __init__(self, answers: Optional[Callable[[str], str]] = None) -> None:
        self.answers = answers

    def prompt(self, text: str) -> None:
        print(f"[display] {text}", flush=True)


def run_session(
    plan_path: str | Path,
    participant: str,
    *,
    out: str | Path = "sessions",
    resume: bool = False,
    display: Optional[bool] = None,
    simulate: bool = False,
    progress: Callable[[str], None] = print,
) -> Path:
    """Runs (or resumes) a participant's session; the participant's folder.

    With ``rig.virtual_human = false`` a person holds the handle: each trial
    starts on SPACE on the display (Esc ends it with the controlled stop),
    practice repeats on R, the questionnaire takes digit keys. With the
    virtual human the session runs unattended (no rests, no questionnaire,
    an aborted trial re-run up to :data:`MAX_ATTEMPTS` times).
    ``simulate``: every trial simulated, whatever ``session.rig`` says
    (recorded in session.json).
    """
    s = Session(plan_path, participant, out)
    if simulate:
        if not s.plan.rig.virtual_human:
            raise ValueError("--simulate: the plan has a person at the handle (rig.virtual_human = false); "
                             "a simulation needs the virtual human")
        s.plan.session.rig = False
        s.simulated = True
    s.create(resume)
    lost = s.recover() if resume else []
    for name in lost:
        progress(f"resume: {name} was interrupted; its trial runs again as a new attempt")
    ran = json.loads((s.folder / "session.json").read_text())["trials_run"]
    if ran != s.trials_run:
        raise ValueError(f"--simulate: this session's trials ran {ran}; resume it the same way")
    person = not s.plan.rig.virtual_human
    use_display = s.plan.display.enabled if display is None else display
    if person and not use_display:
        raise ValueError("display.enabled: a session with a person (rig.virtual_human = false) needs the display "
                         "(the start key, Esc, the prompts); set [display] enabled = true")
    if not s.plan.session.rig and use_display:
        raise ValueError("session.rig: the display follows the rig's log; set session.rig = true or disable [display]")
    screen = None
    if use_display:
        from sensaug.display import DisplayProcess

        screen = DisplayProcess(s.plan, workdir=s.folder)
    try:
        _run_trials(s, screen, person, progress)
    finally:
        if screen is not None:
            screen.close()
    return s.folder


def _show(screen, text: str, folder: Optional[Path] = None) -> None:
    """Shows a prompt and records it (``prompts.csv``: UTC, CLOCK_MONOTONIC ns, text)."""
    if screen is None:
        return
    from sensaug.display import Command

    screen.show(Command(prompt=text))
    if folder is not None:
        _record_prompt(folder, text)


def _record_prompt(folder: Path, text: str) -> None:
    with open(folder / "prompts.csv", "a", newline="") as f:
        csv.writer(f).writerow([_now(), time.monotonic_ns(), text])


def _run_trials(s: Session, screen, person: bool, progress: Callable[[str], None]) -> None:
    rows = s.rows()
    finished = {int(r["trial"]) for r in rows if r["finished"] == "1"}
    attempts: dict[int, int] = {}
    tries: dict[int, int] = {}  # attempts in this invocation (MAX_ATTEMPTS)
    rounds: dict[str, int] = {}
    for r in rows:
        attempts[int(r["trial"])] = max(attempts.get(int(r["trial"]), 0), int(r["attempt"]))
        rounds[r["block"]] = max(rounds.get(r["block"], 0), int(r["round"]))
    blocks = []
    for t in s.trials:
        if not blocks or blocks[-1][0] != t.block:
            blocks.append((t.block, []))
        blocks[-1][1].append(t)
    for bi, (name, trials) in enumerate(blocks):
        practice = trials[0].practice
        rnd = rounds.get(name, 0)
        while True:
            todo = [t for t in trials if t.trial not in finished] if rnd == rounds.get(name, 0) else list(trials)
            for t in todo:
                start_key = person
                while True:
                    attempts[t.trial] = attempts.get(t.trial, 0) + 1
                    tries[t.trial] = tries.get(t.trial, 0) + 1
                    if start_key:
                        _show(screen, f"{name}: trial {t.index + 1} of {len(trials)}. Press SPACE to start.", s.folder)
                        if screen.wait_key({"space"}) is None:
                            raise RuntimeError("display: the window closed before the trial started; --resume continues")
                    row = _run_trial(s, t, rnd, attempts[t.trial], screen, progress)
                    if row["finished"]:
                        finished.add(t.trial)
                        break
                    if not person and tries[t.trial] >= MAX_ATTEMPTS:
                        raise RuntimeError(f"trial {t.trial} ({name} {t.index}): {tries[t.trial]} attempts in a row stopped "
                                           f"({row['stop_reason']}); see {s.folder / row['folder']}; --resume tries again")
                    if person:
                        _show(screen, f"Trial stopped ({row['stop_reason']}). SPACE: run it again, Q: end the session.", s.folder)
                        if screen.wait_key({"space", "q"}) != "space":
                            raise RuntimeError("session ended by the experimenter; --resume continues it")
                        start_key = False  # that SPACE starts the new attempt
            if not (practice and person):
                break
            _show(screen, "Practice done. R: practise again, SPACE: continue.", s.folder)
            if screen.wait_key({"r", "space"}) != "r":
                break
            rnd += 1
        if person and not practice:
            _questionnaire(s, screen, name)
            rest = s.plan.session.rest_s
            if rest > 0 and bi + 1 < len(blocks):
                t_end = time.monotonic() + rest
                while (left := t_end - time.monotonic()) > 0:
                    _show(screen, f"Rest: {math.ceil(left)} s", s.folder)
                    time.sleep(min(1.0, left))
    _show(screen, "Thank you! The session is over.", s.folder)


def _questionnaire(s: Session, screen, block: str) -> None:
    questions = s.plan.session.questionnaire
    if not questions:
        return
    path = s.folder / "questionnaire.csv"
    for q in questions:
        _show(screen, f"{q}  (press 1-7)", s.folder)
        answer = screen.wait_key({str(i) for i in range(1, 8)})
        new = not path.exists()
        with open(path, "a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["block", "question", "answer", "time_utc"])
            w.writerow([block, q, answer or "", _now()])
            f.flush()
            os.fsync(f.fileno())


def _run_trial(s: Session, t: SessionTrial, rnd: int, attempt: int, screen, progress) -> dict:
    rel = f"trials/{t.trial:03d}_{t.block}_{t.index:02d}_r{rnd}_a{attempt}"
    folder = s.folder / rel
    folder.mkdir(parents=True, exist_ok=False)
    start = _now()
    row: dict[str, Any] = {
        "trial": t.trial, "block": t.block, "index": t.index, "practice": int(t.practice), "round": rnd,
        "attempt": attempt, "condition": json.dumps(t.condition), "seed": t.seed, "start_utc": start, "folder": rel,
    }
    if s.plan.session.rig and not s.simulated:
        from sensaug.rig import run_virtual_rig

        if screen is not None:
            _record_prompt(s.folder, f"(trial {rel})")
        run = run_virtual_rig(t.config, out=folder, display=screen)
        stopped_by_display = bool((run.display or {}).get("stopped_loop"))
        stopped_by_key = bool((run.stop_key or {}).get("stopped_loop"))
        reason = (run.display["event"] if stopped_by_display
                  else "stop key" if stopped_by_key else run.stats["stop_reason"])
        row.update(stop_reason=reason, finished=int(run.stats["stop_reason"] in FINISHED
                                                    and not stopped_by_display and not stopped_by_key))
        row.update(_metrics_rig(run))
        if run.display:
            row.update(display_frames=run.display.get("frames"), display_dropped=run.display.get("dropped"),
                       display_latency_p50_ms=run.display.get("latency_p50_ms"),
                       display_latency_p99_ms=run.display.get("latency_p99_ms"), display_event=run.display.get("event"))
    else:
        from sensaug import experiment
        from sensaug.sweep import trial_metrics

        trial = experiment.run(t.config)
        trial.save(folder / "trial_log.csv")
        t.config.to_toml(folder / "trial_config.toml")
        row.update(stop_reason="completed", finished=1, **trial_metrics(trial))
    if t.config.rig.virtual_human:
        row["truth_Lhh"] = float(t.config.partner.gains[2]) if t.config.partner.gains is not None else None
    row = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}
    _fsync_append(s.manifest, row)
    progress(f"{rel}: {row['stop_reason']}" + (f", Lhh^ {row['Lhh_hat']:.4f}" if row.get("Lhh_hat") is not None else ""))
    return row


# --- reading ------------------------------------------------------------------

class LoadedSession:
    """A participant's folder: ``manifest`` (DataFrame, one row per attempt),
    ``info`` (session.json), ``log(trial)`` (the finished attempt's log, read
    when asked), ``plot_blocks(out)`` (a summary figure per block)."""

    def __init__(self, folder: str | Path) -> None:
        import pandas as pd

        self.folder = Path(folder)
        self.info = json.loads((self.folder / "session.json").read_text())
        self.manifest = pd.read_csv(self.folder / "manifest.csv")

    def finished(self):
        return self.manifest[self.manifest["finished"] == 1]

    def summary(self):
        """Per block (in run order): finished trials, the mean and std of the
        headline metrics; the virtual human's Lhh where there is one (never
        with a person at the handle)."""
        df = self.finished()
        cols = [c for c in ("Lhh_hat", "tau_h_rmse", "rmse_own", "rmse_integrated", "truth_Lhh",
                            "display_latency_p99_ms") if c in df and df[c].notna().any()]
        g = df.groupby("block", sort=False)
        out = g[cols].mean()
        if "Lhh_hat" in cols:
            out.insert(1, "Lhh_hat_std", g["Lhh_hat"].std())
        out.insert(0, "trials", g.size())
        return out

    def log(self, trial: int):
        from sensaug.logs import load_log

        rows = self.finished()
        rows = rows[rows["trial"] == trial]
        if rows.empty:
            raise ValueError(f"trial: {trial} has no finished attempt in {self.folder}")
        d = self.folder / rows.iloc[-1]["folder"]
        return load_log(d / ("rig_log.csv" if (d / "rig_log.csv").exists() else "trial_log.csv"))

    def display_log(self, trial: int):
        from sensaug.display import load_display_log

        rows = self.finished()
        rows = rows[rows["trial"] == trial]
        return load_display_log(self.folder / rows.iloc[-1]["folder"] / "display_log.csv")

    def plot_blocks(self, out: str | Path) -> list[Path]:
        """One PNG per block: each finished trial's headline metrics."""
        import matplotlib.pyplot as plt
        from matplotlib.ticker import MaxNLocator

        from sensaug.units import physical

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        df = self.finished()
        # The plan's position unit names the axes (sensaug.units).
        unit = ScenarioConfig.from_toml(self.folder / "plan.toml").rig.position_unit
        pos, gain = physical("pos", unit), physical("trq/pos", unit)
        for block, g in df.groupby("block", sort=False):
            cols = [c for c in ("Lhh_hat", "tau_h_rmse", "rmse_own", "rmse_integrated") if g[c].notna().any()]
            if not cols:
                continue
            fig, axes = plt.subplots(1, len(cols), figsize=(4 * len(cols), 3.2), squeeze=False)
            for ax, c in zip(axes[0], cols):
                ax.plot(g["index"] + 1, g[c], "o-")
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
                ax.ticklabel_format(axis="y", useOffset=False)
                if c == "Lhh_hat" and g["truth_Lhh"].notna().any():
                    ax.axhline(g["truth_Lhh"].iloc[0], color="k", ls="--", lw=1, label="virtual human's Lhh")
                    ax.legend(fontsize=8)
                ax.set_xlabel("trial in block")
                ax.set_ylabel({"Lhh_hat": f"Lhh^ ({gain})", "tau_h_rmse": f"partner-target RMSE ({pos})",
                               "rmse_own": f"(x - tau)^ RMSE own ({pos})",
                               "rmse_integrated": f"(x - tau)^ RMSE integrated ({pos})"}[c])
            fig.suptitle(f"{self.info['participant']}: block {block}")
            fig.tight_layout()
            path = out / f"block_{block}.png"
            fig.savefig(path, dpi=100)
            plt.close(fig)
            written.append(path)
        return written


def load_session(folder: str | Path) -> LoadedSession:
    """A participant's session folder (see :class:`LoadedSession`)."""
    return LoadedSession(folder)
