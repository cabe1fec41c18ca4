"""Typed configuration tables, generated from the JSON Schema of
crates/sensaug-config by scripts/gen_config_types.py: do not edit.

Every field, default and description comes from the Rust schema; the
bounds are enforced there (``sensaug.config`` validates through it).
"""

# ruff: noqa: E501
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Callable, ClassVar, Literal, Self, Sequence, Union

import numpy as np

#: A covariance: N diagonal entries or an N x N nested list (or array).
Covariance = Union[Sequence[float], Sequence[Sequence[float]], np.ndarray]


class _Table:
    """A table of the schema: built from a plain dict by :meth:`from_dict`."""

    #: Field -> converter of the field's plain value (nested tables, shapes).
    _nested: ClassVar[dict[str, Callable[[Any], Any]]] = {}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Self:
        """From a plain dict as the schema describes it (already validated);
        a shape's ``kind`` tag is dropped (it is the class, not a field)."""
        kw = dict(d)
        if "kind" not in {f.name for f in fields(cls)}:  # type: ignore[arg-type]
            kw.pop("kind", None)
        for name, convert in cls._nested.items():
            if kw.get(name) is not None:
                kw[name] = convert(kw[name])
        return cls(**kw)


@dataclass
class Constant(_Table):
    """A constant offset."""

    kind: ClassVar[str] = 'constant'
    value: float
    """Offset (position unit)."""


@dataclass
class Square(_Table):
    """+amplitude for the first half of each period, -amplitude after."""

    kind: ClassVar[str] = 'square'
    amplitude: float
    """Amplitude (position unit)."""
    period_s: float
    """Period (s)."""


@dataclass
class RoundedSquare(_Table):
    """amplitude * cbrt(sin(2 pi t / period)): the Hi5 target (8 deg, 4 s)."""

    kind: ClassVar[str] = 'rounded_square'
    amplitude: float
    """Amplitude (position unit)."""
    period_s: float
    """Period (s)."""


@dataclass
class Chirp(_Table):
    """Linear chirp from f0_hz to f1_hz over duration_s, then at f1_hz."""

    kind: ClassVar[str] = 'chirp'
    amplitude: float
    """Amplitude (position unit)."""
    f0_hz: float
    """Start frequency (Hz)."""
    f1_hz: float
    """End frequency (Hz)."""
    duration_s: float
    """Sweep duration (s)."""


@dataclass
class Harmonics(_Table):
    """amplitude * sum over k = 1..harmonics of sin(k omega t) (cos if cosine)."""

    kind: ClassVar[str] = 'harmonics'
    amplitude: float
    """Amplitude of each harmonic (position unit)."""
    omega_rad_s: float
    """Fundamental angular frequency (rad/s)."""
    cosine: bool = False
    """Cosines instead of sines."""
    harmonics: int = 3
    """Number of harmonics."""


@dataclass
class Sampled(_Table):
    """Samples every dt_s from t = 0, linearly interpolated, held at the ends."""

    kind: ClassVar[str] = 'sampled'
    samples: list[float]
    """The samples (position unit)."""
    dt_s: float
    """Sample spacing (s)."""


Shape = Union[Constant, Square, RoundedSquare, Chirp, Harmonics, Sampled]
#: Shape class by its ``kind``.
SHAPES: dict[str, type] = {'constant': Constant, 'square': Square, 'rounded_square': RoundedSquare, 'chirp': Chirp, 'harmonics': Harmonics, 'sampled': Sampled}


def _shapes(items: list[Any]) -> list[Shape]:
    out = []
    for s in items:
        if isinstance(s, dict):
            s = SHAPES[s["kind"]].from_dict(s)
        out.append(s)
    return out


def _list_of(conv: Callable[[dict[str, Any]], Any]) -> Callable[[list[Any]], list[Any]]:
    return lambda items: [conv(x) if isinstance(x, dict) else x for x in items]


@dataclass
class DisplayConfig(_Table):
    """`[display]`: the participant's monitor (docs/person.md). Positions are in the controller's
    position unit (`rig.position_unit`).
    """

    direction: Literal["right", "left", "up", "down"] = 'right'
    """Which way a positive position moves the cursor: "right", "left", "up" or "down"."""
    dots: int = 20
    """Visual noise: number of dots drawn around the target in integration phases when sigma_v >
    0.
    """
    enabled: bool = False
    """Open the display with `sensaug rig`, `demo` and `session`."""
    freeze_timeout_ms: float = 250.0
    """The display counts as frozen when it has drawn no frame for this long (ms); the session
    then acts as on_freeze says.
    """
    fullscreen: bool = True
    """Full screen on the rig's monitor; false: a window of width_px x height_px."""
    height_px: int = 720
    """Window height (px) when not full screen."""
    on_freeze: Literal["stop", "continue"] = 'stop'
    """On a frozen display: "stop" (the controlled stop) or "continue" (only with
    rig.virtual_human = true).
    """
    px_per_unit: float = 25.0
    """Scale: pixels per position unit (px per deg in the Hi5 presets)."""
    refresh_ms: float = 100.0
    """Visual noise: the dots are re-drawn every refresh_ms (ms)."""
    seed: int = 0
    """Seed of the dots: the n-th refresh's dots are a function of (seed, n), so a trial can be
    re-rendered exactly offline.
    """
    sigma_v: float = 0.0
    """Visual noise: std of the dots around the true target (position unit); 0 draws one target.
    Applies in integration phases.
    """
    width_px: int = 1280
    """Window width (px) when not full screen."""


@dataclass
class IncludedFile(_Table):
    """A file a configuration included (`included`)."""

    path: str
    """The file as opened: the `include` entry joined to the including file's folder, made
    absolute.
    """
    sha256: str
    """SHA-256 of the file's bytes as read (64 lowercase hex digits)."""


@dataclass
class GainDriftConfig(_Table):
    """`[partner.human.gain_drift]`: each gain is L (1 + delta), delta a mean-reverting random
    walk clipped at +-3 std.
    """

    std: float = 0.1
    """Stationary relative std of delta (< 1/3, so a gain keeps its sign)."""
    time_constant_s: float = 10.0
    """Its time constant (s)."""


@dataclass
class HumanConfig(_Table):
    """`[partner.human]`: a human-like virtual partner (docs/model.md, "The human-like partner"):
    it acts on what it perceived a sensorimotor delay ago, with signal-dependent motor noise
    and optionally drifting gains. Absent: the paper's virtual human, exactly.
    """

    gain_drift: GainDriftConfig | None = None
    """Slow drift of the gains; absent: none."""
    motor_noise_gain: float = 0.0
    """k_m: white noise of std k_m |c| on the partner's command c (the constant floor is
    world.motor_noise_std).
    """
    proprioceptive_delay_ms: float = 0.0
    """Proprioceptive delay (ms) on the velocity term."""
    seed: int = 24
    """Seed of the partner's motor noise and drift (its own stream)."""
    visual_delay_ms: float = 0.0
    """Visual delay (ms) on the target terms x - tau and x - tau_h (the cursor and the target are
    both seen on the monitor that late).
    """

    _nested = {'gain_drift': GainDriftConfig.from_dict}


@dataclass
class PartnerIntegrationConfig(_Table):
    """`[partner.integration]`: the partner runs the robot's controller on the mirrored protocol
    (the robot's filter settings; needs estimates_robot): in integration phases it sees its
    own target through white noise and fuses the robot's estimated target with it.
    """

    integrate: bool = True
    """Let the integrated estimate drive the partner's command."""
    seed: int = 2
    """Seed of the partner's target-view noise."""
    target_noise_std: float = 0.0
    """Std of the white noise on the partner's view of its own target in every integration phase
    (position unit).
    """


@dataclass
class PartnerConfig(_Table):
    """`[partner]`: the virtual human, with imposed gains or LQR weights (give one, not both)."""

    acts_on: Literal["measured", "true"] = 'measured'
    """Which handle state the virtual human's torque law reads (simulation only): "measured", the
    robot's noisy sample (one position-noise draw in both x - tau and x - tau_h, as inside the
    rig loop), or "true".
    """
    estimates_robot: bool = False
    """The partner also identifies the robot (the simulation section)."""
    gains: list[float] | None = None
    """Imposed gains [Lhx, Lhv, Lhh] over xi = [x - tau, xdot, x - tau_h] (the Hi5 virtual human:
    [0, 0, Lhh]).
    """
    human: HumanConfig | None = None
    """A human-like partner; absent: the paper's virtual human."""
    integration: PartnerIntegrationConfig | None = None
    """The partner's goal integration (the simulation section's "Goal integration"); absent: off,
    the partner tracks its own target exactly.
    """
    q_pos: float | None = None
    """LQR weight on the partner's own position error (instead of gains)."""
    q_vel: float | None = None
    """LQR weight on the velocity (with q_pos; default 0)."""
    torque_limit: float = 1000.0
    """Torque limit (model torque unit)."""

    _nested = {'human': HumanConfig.from_dict, 'integration': PartnerIntegrationConfig.from_dict}


@dataclass
class PhaseConfig(_Table):
    """One phase (`[[phases]]`)."""

    kind: Literal["gains", "trajectory", "integration"]
    """What the robot estimates: "gains", "trajectory" or "integration"."""
    duration_s: float
    """Duration (s), at least one tick."""
    robot_target: list[Shape]
    """The robot's target tau: a sum of 1 to 3 shapes (position unit)."""
    partner_target: list[Shape]
    """The partner's target tau_h: a sum of 1 to 3 shapes (position unit)."""
    target_noise_std: float = 0.0
    """Std of the white noise on the robot's view of its target (position unit); used in
    integration phases.
    """

    _nested = {'robot_target': _shapes, 'partner_target': _shapes}


@dataclass
class PlantConfig(_Table):
    """`[plant]`: the handle, `M xdd + C xd = u + u_h + eps` (eq.dynamics)."""

    coulomb: float = 0.0
    """Coulomb friction of the simulated handle (model torque unit)."""
    damping: float = 0.0
    """Viscous damping C (model torque unit per position unit per s)."""
    dt_s: float = 0.001
    """Control period dt (s): 1e-4 to 0.1."""
    mass: float = 0.0035
    """Inertia M (model mass unit: 0.0035 for the Hi5 in degrees, kg in the simulation section)."""


@dataclass
class RigCia402Config(_Table):
    """`[rig.cia402]`: settings of the CiA 402 profile (`rig.drive = "cia402"`; ignored on the
    Hi5).
    """

    freshness: Literal["auto", "sync_counter_echo", "standard"] = 'auto'
    """How the master tells a TPDO answering this tick's SYNC from a late or replayed one: "auto"
    (the SYNC counter echo 0x2000 if the drive's dictionary has it, else standard),
    "sync_counter_echo" (a drive without 0x2000 is refused) or "standard" (judged from the
    bus: a TPDO received after SYNC k and before SYNC k+1 answers SYNC k; a replay inside that
    window goes unseen, docs/safety.md). The statistics' drive.freshness says which ran.
    """
    heartbeat_timeout_ms: int = 100
    """The master's heartbeat consumer time for the drive (ms): a drive heartbeat missing this
    long stops the run with an emergency stop ("drive fault: the drive's heartbeat lost"). The
    drive is set to beat every half of it (0x1017). At most 3 x rig.watchdog_ms (the drive
    watches the master within the watchdog; the master watches the drive within a small
    multiple of it).
    """


@dataclass
class RigFrictionConfig(_Table):
    """`[rig.friction]`: the handle's Coulomb and viscous friction, compensated by the loop
    before its model applies (the paper's Hi5 is modelled "after Coulomb and viscous friction
    compensation"): the command gains `viscous_nm_s_per_rad v + coulomb_nm s` on the measured
    velocity `v` (rad/s), the Coulomb term's sign `s` the velocity's while the handle moves
    and the asked torque's at rest, ramped over `coulomb_band_rad_s` and
    `coulomb_torque_band_nm` (docs/hardware.md, "Calibrating the handle"), inside the torque
    limit. `sensaug calibrate` identifies both and writes this table. The simulation ignores
    it (its handle is `[plant]`).
    """

    coulomb_band_rad_s: float = 0.002
    """The Coulomb term's velocity band (rad/s): below this speed its sign blends linearly from
    the velocity's to the asked torque's, so the compensation is continuous through zero
    velocity and never chatters on the velocity report's noise; keep it above that noise (the
    default is 2000 steps of the Hi5 report's 1e-6 rad/s; a drive that reports the finite
    difference of its encoder needs several counts per period).
    """
    coulomb_nm: float = 0.0
    """Coulomb friction to compensate (N m); 0: none. At most `rig.torque_limit_nm`."""
    coulomb_torque_band_nm: float = 0.0005
    """The Coulomb term's torque band at rest (N m): at rest its sign is `clamp(tau /
    coulomb_torque_band_nm, -1, 1)` of the torque `tau` the controller and the partner ask, so
    a push breaks the handle's stiction and a torque dithering about zero does not flip it;
    keep it at a few of the drive's torque steps or more.
    """
    viscous_nm_s_per_rad: float = 0.0
    """Viscous friction to compensate (N m s/rad); 0: none. Its gain per tick,
    `viscous_nm_s_per_rad plant.dt_s / plant.mass`, at most 1/2.
    """


@dataclass
class RigRangeConfig(_Table):
    """`[rig.range]`: the handle's range of motion and speed, in degrees whatever
    `rig.position_unit` (like every `[rig]` field, the unit is in the name), enforced by
    `sensaug-rt` every tick (docs/safety.md, "Range of motion"; the defaults and their
    sources: docs/person.md). The simulation ignores it.
    """

    hard_max_deg: float = 50.0
    """Hard limit, high side (deg). Above `soft_max_deg`."""
    hard_min_deg: float = -50.0
    """Hard limit, low side (deg): a measured position below it stops the run with the controlled
    stop ("range limit"). Below `soft_min_deg`.
    """
    hard_speed_deg_s: float = 400.0
    """Hard speed limit (deg/s): a measured speed above it stops the run with the controlled stop
    ("range limit"). Above `soft_speed_deg_s`, below `rig.max_feedback_velocity_rad_s`.
    """
    ramp_width_deg: float = 5.0
    """Width of the ramp-down inside each soft end stop (deg): the controller's torque toward a
    soft end stop is scaled from 1, at `ramp_width_deg` from it, down to 0 at it (the
    partner's is not).
    """
    soft_max_deg: float = 40.0
    """Soft end stop, high side (deg)."""
    soft_min_deg: float = -40.0
    """Soft end stop, low side (deg): below it a virtual wall (a spring-damper,
    `wall_stiffness_nm_per_deg`, `wall_damping_nm_s_per_deg`) pushes the handle back.
    """
    soft_speed_deg_s: float = 200.0
    """Soft speed limit (deg/s): above it a damping torque on the excess speed
    (`speed_damping_nm_s_per_deg`) slows the handle.
    """
    speed_damping_nm_s_per_deg: float | None = None
    """Damping on the speed above `soft_speed_deg_s` (N m s/deg). Absent: `plant.mass / (8
    plant.dt_s)`, as the wall's (the two together critically damped with one tick of feedback
    delay).
    """
    wall_damping_nm_s_per_deg: float | None = None
    """The wall's damping beyond a soft end stop (N m s/deg); the wall only ever pushes back into
    the window. Absent: `plant.mass / (8 plant.dt_s)` (0.00764 N m s/deg for the Hi5 at 1 kHz:
    1/8 of the speed per tick).
    """
    wall_stiffness_nm_per_deg: float | None = None
    """The wall's stiffness beyond a soft end stop (N m/deg). Absent: `plant.mass / (8
    plant.dt_s)^2` (0.955 N m/deg for the Hi5 at 1 kHz; the wall's natural frequency is 1/8
    rad per tick).
    """


@dataclass
class RealtimeConfig(_Table):
    """`[rig.realtime]`: thread settings of the loop; each falls back with a warning if the OS
    refuses it.
    """

    cpu: int | None = None
    """CPU to pin the loop thread to; absent: no pinning."""
    fifo_priority: int | None = None
    """SCHED_FIFO priority 1..99; absent keeps the default scheduler."""
    mlockall: bool = True
    """Lock all memory (mlockall) before the loop."""
    spin_us: int = 0
    """Sleep-then-spin wake-up (us; 0: off, the tick sleeps until its deadline). With spin_us > 0
    each tick sleeps until spin_us before its deadline, then busy-waits on the clock until the
    deadline: an OS timer wake-up later than its target by less than spin_us no longer delays
    the tick. The cost: the loop's cpu is busy for spin_us of every period (100 us at 1 kHz:
    10% of a cpu). Best with `cpu` (the spin stays on the loop's own cpu, which the log writer
    avoids) and `fifo_priority` (no ordinary thread preempts the spin); with
    /dev/cpu_dma_latency held at 0 the idle cpu polls anyway (no deep idle state), so the spin
    costs no more power than idling would, though it gives its cpu to no one. Must be below
    half the loop period.
    """


@dataclass
class RigConfig(_Table):
    """`[rig]`: the real-time loop, its CAN link, its safety limits and outputs."""

    can: str = 'udp:47100'
    """CAN link: "udp:<port>" (loopback virtual bus, port 1..65535) or "socketcan:<ifname>"."""
    cia402: RigCia402Config = field(default_factory=lambda: RigCia402Config.from_dict({'freshness': 'auto', 'heartbeat_timeout_ms': 100}))
    """CiA 402 profile settings."""
    drive: Literal["hi5", "cia402"] = 'hi5'
    """Drive profile: "hi5" or "cia402" (its units are read from the drive over SDO; its
    heartbeat consumer is armed with `watchdog_ms`).
    """
    feedback_step_margin_rad: float = 0.01
    """Feedback plausibility: a position step between two feedbacks larger than
    `max_feedback_velocity_rad_s` times their time apart plus this margin (rad) stops the loop
    ("implausible feedback").
    """
    feedback_timeout_ms: float = 20.0
    """Feedback older than this stops the loop with an emergency stop (ms)."""
    feedback_velocity_margin_rad_s: float = 0.05
    """Feedback consistency: a feedback velocity farther from the velocity the position's change
    implies than the plant allows (its largest acceleration, `torque_limit_nm / plant.mass`,
    over the time between the two feedbacks) plus this margin (rad/s: encoder quantisation, a
    drive's velocity filter) stops the loop ("implausible feedback", docs/safety.md).
    """
    friction: RigFrictionConfig = field(default_factory=lambda: RigFrictionConfig.from_dict({'coulomb_band_rad_s': 0.002, 'coulomb_nm': 0.0, 'coulomb_torque_band_nm': 0.0005, 'viscous_nm_s_per_rad': 0.0}))
    """The handle's friction the loop compensates (`sensaug calibrate` identifies it;
    docs/hardware.md, "Calibrating the handle"). Off by default (both zero).
    """
    log: str = 'out/rig_log.csv'
    """Log file (CSV with metadata, docs/logs.md)."""
    max_estimator_errors: int = 10
    """Degraded run: more than this many estimator errors (filter recoveries) or non-finite
    controller outputs stops the run with the controlled stop ("degraded").
    """
    max_feedback_velocity_rad_s: float = 8.0
    """Feedback plausibility: a feedback velocity beyond this (rad/s, the drive's velocity limit;
    the virtual Hi5 faults OVERSPEED above 8) stops the loop ("implausible feedback",
    docs/safety.md).
    """
    max_missing_feedback_fraction: float = 0.5
    """Degraded run: more than this fraction of ticks without fresh feedback (over the run so
    far, the first second counted as a whole second) turns the torque off and stops
    ("degraded").
    """
    max_stale_feedback_ticks: int = 100
    """Degraded run: more than this many consecutive ticks without fresh feedback turns the
    torque off and stops ("degraded").
    """
    node_id: int = 1
    """Drive node id (CiA 402: 1..15, node 0 is NMT broadcast)."""
    position_unit: Literal["deg", "rad", "m"] = 'deg'
    """Unit of the controller's positions: "deg" or "rad" on the rig (the drive speaks rad and N
    m, and torque is scaled by the same factor), "m" for a simulated linear handle (force in
    N; the rig refuses it; docs/model.md, Units).
    """
    range: RigRangeConfig = field(default_factory=lambda: RigRangeConfig.from_dict({'hard_max_deg': 50.0, 'hard_min_deg': -50.0, 'hard_speed_deg_s': 400.0, 'ramp_width_deg': 5.0, 'soft_max_deg': 40.0, 'soft_min_deg': -40.0, 'soft_speed_deg_s': 200.0}))
    """The handle's range of motion and speed for the wrist in it (deg): soft end stops with a
    virtual wall, hard limits, a speed limit (docs/safety.md, "Range of motion").
    """
    realtime: RealtimeConfig = field(default_factory=lambda: RealtimeConfig.from_dict({'mlockall': True, 'spin_us': 0}))
    """Thread settings."""
    ring_capacity: int = 65536
    """Log ring capacity (records)."""
    stats: str = 'out/rig_stats.json'
    """Loop statistics (JSON)."""
    stop_rest_velocity_rad_s: float = 0.01
    """The controlled stop ends (the drive is disabled) once the measured speed is below this
    (rad/s).
    """
    stop_time_constant_s: float = 0.004
    """The controlled stop's velocity time constant (s): the brake is a damping torque
    `-(plant.mass / stop_time_constant_s) v` on the measured velocity, so the handle's speed
    decays by `dt / stop_time_constant_s` of itself per tick. At least two loop periods
    (stable with one period of feedback delay).
    """
    stop_time_limit_s: float = 0.2
    """The controlled stop (every stop but an emergency stop; docs/safety.md, "The controlled
    stop"): the longest it brakes before the drive is disabled (s). 0: torque off at once.
    """
    stop_torque_limit_nm: float = 3.0
    """The controlled stop's largest brake torque (N m); every command is also clamped at
    `torque_limit_nm`.
    """
    torque_limit_nm: float = 3.0
    """Torque limit at the drive (N m)."""
    virtual_human: bool = True
    """Run the virtual human inside the loop (false: a person holds the handle)."""
    watchdog_ms: int = 50
    """Drive command watchdog (ms): the drive disables itself when commands stop for this long
    (Hi5: 5..200, hi5.dbc's SetState.watchdog_ms; CiA 402: 2..200, the drive's heartbeat
    consumer time 0x1016).
    """

    _nested = {'cia402': RigCia402Config.from_dict, 'friction': RigFrictionConfig.from_dict, 'range': RigRangeConfig.from_dict, 'realtime': RealtimeConfig.from_dict}


@dataclass
class SigmaConfig(_Table):
    """`[robot.sigma]`: Merwe scaled sigma points of every UKF."""

    alpha: float = 1.0
    """Spread alpha."""
    beta: float = 2.0
    """Prior-knowledge beta (2 for Gaussians)."""
    kappa: float = 0.0
    """Secondary scaling kappa; n + kappa must be > 0."""


@dataclass
class GainFilterConfig(_Table):
    """`[robot.stage1]`: the gain-estimation UKF (eq.system-extended; 6 states, measurements [x -
    tau, xdot, x - tau_h]). Covariances are per step.
    """

    P0: Covariance = field(default_factory=lambda: [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0])
    """Initial covariance P0 (6 diagonal entries or a 6x6 matrix)."""
    Q: Covariance = field(default_factory=lambda: [0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
    """Process noise Q (6 diagonal entries or a 6x6 matrix)."""
    R: Covariance = field(default_factory=lambda: [1e-07, 1e-07, 1e-07])
    """Measurement noise R (3 diagonal entries or a 3x3 matrix)."""
    gains0: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    """Initial guesses of the partner gains [Lhx, Lhv, Lhh]."""


@dataclass
class TrajectoryFilterConfig(_Table):
    """`[robot.stage2]`: the trajectory-estimation UKF (6 states, measurements [x - tau, xdot]
    and the three gains as pseudo-measurements).
    """

    P0: Covariance = field(default_factory=lambda: [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0])
    """Initial covariance P0 (6 diagonal entries or a 6x6 matrix)."""
    Q: Covariance = field(default_factory=lambda: [0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
    """Process noise Q (6 diagonal entries or a 6x6 matrix)."""
    R: Covariance = field(default_factory=lambda: [1e-07, 1e-07, 1e-07, 1e-07, 1e-07])
    """Measurement noise R (5 diagonal entries or a 5x5 matrix)."""
    gains0: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    """Unused (stage 2 starts from the stage-1 posterior); kept so one filter table fits both
    stages.
    """


@dataclass
class ChannelConfig(_Table):
    """`[robot.stage3.channel]`: how the partner channel's trust adapts (docs/model.md, stage 3).
    The defaults are the design's; the same for every preset.
    """

    gate: float = 4.0
    """Change-point and readmission threshold, in standard deviations of the own position
    innovation.
    """
    hold_max_s: float = 0.25
    """Longest suspension of the partner channel after a target jump (s)."""
    window_n0: float = 80.0
    """Scale of the score window: n0 (1 + R_e / A) ticks, R_e the own view's variance, A the own-
    only filter's.
    """


@dataclass
class IntegratorConfig(_Table):
    """`[robot.stage3]`: goal integration on [x - tau, xdot]: a bank of Kalman filters over the
    partner channel's variance (docs/model.md, stage 3).
    """

    P0: Covariance = field(default_factory=lambda: [0.01, 0.01])
    """Initial covariance P0 of every filter of the bank (2 diagonal entries or a 2x2 matrix)."""
    Q: Covariance = field(default_factory=lambda: [0.01, 0.01])
    """Process noise Q per step (2 diagonal entries or a 2x2 matrix): the first entry is the
    random walk of x - tau standing for the unknown target motion (> 0), the second the
    velocity's (the motor noise, (dt sigma_motor / M)^2).
    """
    R_sensor: Covariance = field(default_factory=lambda: [1e-07, 1e-07])
    """Own sensor noise on [x - tau, xdot] before the phase's target noise is added (2 diagonal
    entries or a 2x2 matrix).
    """
    channel: ChannelConfig = field(default_factory=lambda: ChannelConfig.from_dict({'gate': 4.0, 'hold_max_s': 0.25, 'window_n0': 80.0}))
    """The adaptive partner channel's settings."""

    _nested = {'channel': ChannelConfig.from_dict}


@dataclass
class RobotConfig(_Table):
    """`[robot]`: LQR weights, estimators and the goal-integration switch."""

    gain_window_s: float = 8.0
    """Stage 2's gain pseudo-measurement is the mean of the stage-1 estimate over the last
    gain_window_s of the gain phase (s).
    """
    integrate: bool = True
    """Let the integrated estimate drive control in integration phases."""
    partner_delay: Literal["auto"] | float | None = None
    """The partner model of stages 1 and 2: absent, the paper's (the partner acts on the current
    state); a number of ms, the partner acts on the robot's measured sample that long ago
    (visual and proprioceptive delay alike); "auto", both delays identified online in every
    gain phase (docs/model.md, "A partner with a delay").
    """
    prior_partner_gains: list[float] | None = None
    """Partner gains [Lhx, Lhv, Lhh] to use when no gain phase precedes."""
    q_pos: float = 1.0
    """LQR weight on the position error (its gains come from the reduced 2-state CARE,
    docs/model.md).
    """
    q_vel: float = 0.0
    """LQR weight on the velocity."""
    seed: int = 1
    """Seed of the injected target-view noise."""
    sigma: SigmaConfig = field(default_factory=lambda: SigmaConfig.from_dict({'alpha': 1.0, 'beta': 2.0, 'kappa': 0.0}))
    """Sigma points of every filter."""
    stage1: GainFilterConfig = field(default_factory=lambda: GainFilterConfig.from_dict({'P0': [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0], 'Q': [0.01, 0.01, 0.01, 0.01, 0.01, 0.01], 'R': [1e-07, 1e-07, 1e-07], 'gains0': [0.0, 0.0, 0.0]}))
    """Stage 1 (partner gains)."""
    stage2: TrajectoryFilterConfig = field(default_factory=lambda: TrajectoryFilterConfig.from_dict({'P0': [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0], 'Q': [0.01, 0.01, 0.01, 0.01, 0.01, 0.01], 'R': [1e-07, 1e-07, 1e-07, 1e-07, 1e-07], 'gains0': [0.0, 0.0, 0.0]}))
    """Stage 2 (partner trajectory)."""
    stage3: IntegratorConfig = field(default_factory=lambda: IntegratorConfig.from_dict({'P0': [0.01, 0.01], 'Q': [0.01, 0.01], 'R_sensor': [1e-07, 1e-07], 'channel': {'gate': 4.0, 'hold_max_s': 0.25, 'window_n0': 80.0}}))
    """Stage 3 (goal integration)."""
    torque_limit: float = 1000.0
    """Torque limit of the controller (model torque unit)."""

    _nested = {'sigma': SigmaConfig.from_dict, 'stage1': GainFilterConfig.from_dict, 'stage2': TrajectoryFilterConfig.from_dict, 'stage3': IntegratorConfig.from_dict}


@dataclass
class BlockConfig(_Table):
    """`[[session.blocks]]`: one condition, run `trials` times."""

    name: str
    """Name (in the manifest and the file names)."""
    trials: int
    """Trials in the block."""
    phases: list[int] = field(default_factory=lambda: [])
    """Only this block's phases run (by index into phases); empty: all."""
    practice: bool = False
    """A practice block: run first, in listed order, and repeated while the experimenter asks for
    it (unattended: once); its trials are in the manifest, marked practice.
    """
    set: dict[str, Any] = field(default_factory=lambda: {})
    """The condition: fields of the trial configuration set for this block, by dotted path (as in
    `sensaug sweep`), e.g. `{ "partner.gains.lhh" = 1.5, "display.sigma_v" = 2.0 }`.
    """


@dataclass
class SessionConfig(_Table):
    """`[session]`: a plan of blocks of trials for `sensaug session` (docs/person.md). The rest
    of the file is the base trial.
    """

    blocks: list[BlockConfig]
    """The blocks; practice blocks first, then the others in `order`."""
    order: Literal["fixed", "latin_square", "shuffle"] = 'fixed'
    """Order of the non-practice blocks per participant: "fixed", "latin_square" or "shuffle"."""
    questionnaire: list[str] = field(default_factory=lambda: [])
    """Questions asked after each block (answers in the manifest's questionnaire file); empty:
    none.
    """
    rest_s: float = 0.0
    """Rest after each block (s), with a prompt on the display; 0: none."""
    rig: bool = True
    """Run on the virtual rig (sensaug-rt, true) or simulated (false)."""
    seed: int = 0
    """Seed of the shuffle and of the trials: trial j of a block runs with seed + j (world.seed =
    it, robot.seed and partner.integration.seed offset as in `sensaug sweep`) unless the block
    sets a seed.
    """

    _nested = {'blocks': _list_of(BlockConfig.from_dict)}


@dataclass
class WorldConfig(_Table):
    """`[world]`: simulation only (the rig is the world and ignores it)."""

    motor_noise_std: float = 0.001
    """Std of the motor noise eps added to the summed torque (model torque unit)."""
    position_noise_std: float = 0.00031622776601683794
    """Std of the position sensor noise (position unit)."""
    seed: int = 0
    """Seed of the motor and sensor noise."""
    v0: float = 0.0
    """Initial velocity (position unit/s)."""
    velocity_noise_std: float = 0.00031622776601683794
    """Std of the velocity sensor noise (position unit/s)."""
    x0: float = 0.0
    """Initial position (position unit)."""


@dataclass
class ScenarioConfig(_Table):
    """A whole trial: the protocol's phases, the handle, the simulated world, the robot, its
    partner and the real-time rig. Every table but `phases` may be left out (all defaults).
    """

    phases: list[PhaseConfig]
    """The protocol: 1 to 4 phases run in order."""
    display: DisplayConfig = field(default_factory=lambda: DisplayConfig.from_dict({'direction': 'right', 'dots': 20, 'enabled': False, 'freeze_timeout_ms': 250.0, 'fullscreen': True, 'height_px': 720, 'on_freeze': 'stop', 'px_per_unit': 25.0, 'refresh_ms': 100.0, 'seed': 0, 'sigma_v': 0.0, 'width_px': 1280}))
    """The participant's display (Python `sensaug.display`; the loop ignores it)."""
    include: list[str] | None = None
    """Files whose tables this file takes in, each path relative to this file (`include =
    ["calibration.toml"]`), merged when the file is read (`sensaug-rt CONFIG`,
    `ScenarioConfig.from_toml(path)`); a setting may be given in one file only
    (docs/config.md, "Includes"). Text and tables read without a file cannot include.
    """
    included: list[IncludedFile] | None = None
    """Written when the file is read, not by hand: each file the configuration included, its path
    and SHA-256, so that a trial's log says which files (which handle calibration) it ran
    with.
    """
    partner: PartnerConfig = field(default_factory=lambda: PartnerConfig.from_dict({'acts_on': 'measured', 'estimates_robot': False, 'gains': [0.0, 0.0, 2.0], 'torque_limit': 1000.0}))
    """The partner: the virtual human (simulation, and inside the rig loop)."""
    plant: PlantConfig = field(default_factory=lambda: PlantConfig.from_dict({'coulomb': 0.0, 'damping': 0.0, 'dt_s': 0.001, 'mass': 0.0035}))
    """The handle as the controller models it."""
    rig: RigConfig = field(default_factory=lambda: RigConfig.from_dict({'can': 'udp:47100', 'cia402': {'freshness': 'auto', 'heartbeat_timeout_ms': 100}, 'drive': 'hi5', 'feedback_step_margin_rad': 0.01, 'feedback_timeout_ms': 20.0, 'feedback_velocity_margin_rad_s': 0.05, 'friction': {'coulomb_band_rad_s': 0.002, 'coulomb_nm': 0.0, 'coulomb_torque_band_nm': 0.0005, 'viscous_nm_s_per_rad': 0.0}, 'log': 'out/rig_log.csv', 'max_estimator_errors': 10, 'max_feedback_velocity_rad_s': 8.0, 'max_missing_feedback_fraction': 0.5, 'max_stale_feedback_ticks': 100, 'node_id': 1, 'position_unit': 'deg', 'range': {'hard_max_deg': 50.0, 'hard_min_deg': -50.0, 'hard_speed_deg_s': 400.0, 'ramp_width_deg': 5.0, 'soft_max_deg': 40.0, 'soft_min_deg': -40.0, 'soft_speed_deg_s': 200.0}, 'realtime': {'mlockall': True, 'spin_us': 0}, 'ring_capacity': 65536, 'stats': 'out/rig_stats.json', 'stop_rest_velocity_rad_s': 0.01, 'stop_time_constant_s': 0.004, 'stop_time_limit_s': 0.2, 'stop_torque_limit_nm': 3.0, 'torque_limit_nm': 3.0, 'virtual_human': True, 'watchdog_ms': 50}))
    """The real-time loop and its CAN link (`sensaug-rt`; the simulation ignores it)."""
    robot: RobotConfig = field(default_factory=lambda: RobotConfig.from_dict({'gain_window_s': 8.0, 'integrate': True, 'q_pos': 1.0, 'q_vel': 0.0, 'seed': 1, 'sigma': {'alpha': 1.0, 'beta': 2.0, 'kappa': 0.0}, 'stage1': {'P0': [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0], 'Q': [0.01, 0.01, 0.01, 0.01, 0.01, 0.01], 'R': [1e-07, 1e-07, 1e-07], 'gains0': [0.0, 0.0, 0.0]}, 'stage2': {'P0': [0.0001, 0.0001, 0.0001, 1.0, 1.0, 1.0], 'Q': [0.01, 0.01, 0.01, 0.01, 0.01, 0.01], 'R': [1e-07, 1e-07, 1e-07, 1e-07, 1e-07], 'gains0': [0.0, 0.0, 0.0]}, 'stage3': {'P0': [0.01, 0.01], 'Q': [0.01, 0.01], 'R_sensor': [1e-07, 1e-07], 'channel': {'gate': 4.0, 'hold_max_s': 0.25, 'window_n0': 80.0}}, 'torque_limit': 1000.0}))
    """The robot's controller and estimators."""
    session: SessionConfig | None = None
    """A session plan: blocks of trials of this base trial (`sensaug session`; a single trial
    ignores it).
    """
    world: WorldConfig = field(default_factory=lambda: WorldConfig.from_dict({'motor_noise_std': 0.001, 'position_noise_std': 0.00031622776601683794, 'seed': 0, 'v0': 0.0, 'velocity_noise_std': 0.00031622776601683794, 'x0': 0.0}))
    """Simulation only: noise, seed and initial state of the simulated world."""

    _nested = {'phases': _list_of(PhaseConfig.from_dict), 'display': DisplayConfig.from_dict, 'included': _list_of(IncludedFile.from_dict), 'partner': PartnerConfig.from_dict, 'plant': PlantConfig.from_dict, 'rig': RigConfig.from_dict, 'robot': RobotConfig.from_dict, 'session': SessionConfig.from_dict, 'world': WorldConfig.from_dict}
