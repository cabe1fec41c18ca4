//! The per-tick and set-up problems that are timed and counted, defined once:
//! `benches/numerics.rs` (criterion) and `examples/perf_harness.rs`
//! (per-call timings and callgrind instruction counts for `BENCHMARKS.md`)
//! both run these closures. `benches/compare_oracles.py` times filterpy and
//! scipy on the same problems (same matrices, same measurements).
#![allow(dead_code)]

#[path = "../../tests/common/mod.rs"]
mod common;

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};
use sensaug_core::controller::Robot;
use sensaug_core::estimator::{GainEstimator, TrajectoryEstimator};
use sensaug_core::goal::{ChannelConfig, GoalIntegrator, GoalIntegratorConfig};
use sensaug_core::protocol::Protocol;
use sensaug_core::riccati::{care, dare};
use sensaug_core::row::Row;
use sensaug_core::world::Scenario;
use std::hint::black_box;

/// One benchmarked call, repeated by the runners.
pub type Call = Box<dyn FnMut()>;

/// A workload: its name and the set-up that returns its call.
pub type Workload = (&'static str, fn() -> Call);

/// Handle mass of the Hi5 experiment (kg m^2), as in `compare_oracles.py`.
pub const MASS: f64 = common::M;
/// Tick (s).
pub const DT: f64 = common::DT;

/// The 3-state system timed here and in `benches/compare_oracles.py`.
pub fn system3() -> (Matrix3<f64>, SMatrix<f64, 3, 1>) {
    (
        Matrix3::new(0.0, 1.0, 0.0, 0.0, -0.1, 1.0, 0.5, 0.0, -1.0),
        SMatrix::<f64, 3, 1>::new(0.0, 0.0, 1.0),
    )
}

// The estimators' settings in the oracle script are the tests' Hi5 ones
// (`tests/common`): `P0 = diag(1e-4 x3, 1 x3)`, `Q = 1e-2 I`, `R = 1e-7 I`,
// Merwe `(1, 2, 0)`; the handle model `(MASS, C = 0, DT)`.
use common::{extended, model};

/// Stage 1: `update(y1)` then `predict(u, dtau, dtau_h)`, 6 states, 3
/// measurements.
pub fn ukf_step_3() -> Call {
    let mut g = GainEstimator::new(model(), &extended::<3>()).expect("valid estimator");
    // Sanity before timing: a step succeeds and stays finite.
    let _ = g
        .update(&Vector3::new(0.1, 0.0, 0.1))
        .expect("first update");
    assert!(g.filter().x().iter().all(|v| v.is_finite()));
    let mut k = 0u64;
    Box::new(move || {
        k += 1;
        let s = (k as f64 * 1e-3).sin();
        let _ = g.update(black_box(&Vector3::new(s, 0.1, s)));
        let _ = g.predict(black_box(0.01 * s), 1e-3, 1e-3);
    })
}

/// Stage 3, the adaptive partner channel's bank of 8 filters: `update(y,
/// channel)` then `predict(u)`, with the Hi5 preset's stage-3 settings at a
/// 1 deg target-view noise; the own measurement and the channel follow a
/// rounded square with a jump every 2000 calls (change points, suspensions).
pub fn goal_integrator_step() -> Call {
    let qv = (DT * 1e-3 / MASS) * (DT * 1e-3 / MASS);
    let cfg = GoalIntegratorConfig {
        x0: Vector2::zeros(),
        P0: Matrix2::identity() * 1e-2,
        Q: Matrix2::new(1e-2, 0.0, 0.0, qv),
        R_own: Matrix2::new(1.0 + 1e-7, 0.0, 0.0, 1e-7),
        channel: ChannelConfig::default(),
    };
    let mut g = GoalIntegrator::new(model(), &cfg).expect("valid integrator");
    let _ = g
        .update(&Vector2::new(0.1, 0.0), Some(0.1))
        .expect("first update");
    assert!(g.estimate(true).iter().all(|v| v.is_finite()));
    let mut k = 0u64;
    Box::new(move || {
        k += 1;
        let jump = if (k / 2000) % 2 == 0 { 8.0 } else { -8.0 };
        let s = jump + (k as f64 * 0.7).sin();
        let _ = g.update(black_box(&Vector2::new(s, 0.0)), black_box(Some(jump)));
        let _ = g.predict(black_box(0.01), 0.0);
    })
}

/// Stage 2: `update(y2)` then `predict`, 6 states, 5 measurements.
pub fn ukf_step_5() -> Call {
    let mut t = TrajectoryEstimator::new(model(), &extended::<5>()).expect("valid estimator");
    let y0 = SVector::<f64, 5>::new(0.1, 0.1, 0.0, 0.0, 2.0);
    let _ = t.update(&y0).expect("first update");
    assert!(t.filter().x().iter().all(|v| v.is_finite()));
    let mut k = 0u64;
    Box::new(move || {
        k += 1;
        let s = (k as f64 * 1e-3).sin();
        let _ = t.update(black_box(&SVector::<f64, 5>::new(s, 0.1, 0.0, 0.0, 2.0)));
        let _ = t.predict(black_box(0.01 * s), 1e-3, 0.0);
    })
}

/// One Riccati solve (`care` or `dare`) of `(A, B)` with `Q = I`, `R = 1`
/// per call; checked to succeed at set-up.
fn riccati_solve<const N: usize, E: 'static>(
    solve: impl Fn(
            &SMatrix<f64, N, N>,
            &SMatrix<f64, N, 1>,
            &SMatrix<f64, N, N>,
            &SMatrix<f64, 1, 1>,
        ) -> Result<SMatrix<f64, N, N>, E>
        + 'static,
    A: SMatrix<f64, N, N>,
    B: SMatrix<f64, N, 1>,
) -> Call {
    let R = SMatrix::<f64, 1, 1>::identity();
    assert!(solve(&A, &B, &SMatrix::identity(), &R).is_ok());
    Box::new(move || {
        let _ = black_box(solve(black_box(&A), &B, &SMatrix::identity(), &R));
    })
}

/// CARE, 2 states (the agents' reduced problem).
pub fn care_2() -> Call {
    let A = Matrix2::new(0.0, 1.0, 0.0, -0.5);
    riccati_solve(care, A, SMatrix::<f64, 2, 1>::new(0.0, 1.0 / MASS))
}

/// CARE, 3 states.
pub fn care_3() -> Call {
    let (A, B) = system3();
    riccati_solve(care, A, B)
}

/// DARE, 2 states (the 1 kHz double integrator).
pub fn dare_2() -> Call {
    let A = Matrix2::new(1.0, 1e-3, 0.0, 1.0);
    riccati_solve(dare, A, SMatrix::<f64, 2, 1>::new(5e-7, 1e-3))
}

/// DARE, 3 states (the 3-state system discretised with step 1e-2).
pub fn dare_3() -> Call {
    let (A3, B3) = system3();
    riccati_solve(dare, Matrix3::identity() + A3 * 1e-2, B3 * 1e-2)
}

/// Length of each phase of the robot-tick workloads (s): longer than the
/// 8 s gain window, so the gain phase's steady state includes it.
pub const TICK_PHASE_S: f64 = 10.0;

/// The robot's tick in one phase of the Hi5 protocol (0 gains, 1 trajectory,
/// 2 integration, target-view noise 1.0), in steady state: the measurements
/// are those of a simulated trial with the same robot (`Scenario`, recorded
/// at set-up), the robot is brought to the phase's first tick outside the
/// timed region, and each call is one tick of that phase, wrapping round to
/// the phase's first tick at its end (the phase index does not change, so no
/// hand-off or restart happens in the timed calls). Until the first wrap the
/// robot reproduces the simulated trial's estimates exactly.
fn robot_tick(phase: usize) -> Call {
    robot_tick_with(phase, common::robot())
}

/// [`robot_tick`] for the robot `cfg`.
fn robot_tick_with(phase: usize, cfg: sensaug_core::controller::RobotConfig) -> Call {
    let phases = common::phases(TICK_PHASE_S, 1.0);
    let mut scenario = Scenario::new(&phases, cfg, common::partner(2.0), common::world(3))
        .expect("valid scenario");
    let mut records = vec![Row::UNKNOWN; scenario.ticks()];
    scenario.run(&mut records).expect("simulated trial");
    let protocol = Protocol::new(&phases, common::DT).expect("valid protocol");
    let mut robot = Robot::new(cfg, protocol).expect("valid robot");
    let phase_ticks = (TICK_PHASE_S / common::DT).round() as u64;
    let (start, end) = (phase as u64 * phase_ticks, (phase as u64 + 1) * phase_ticks);
    let mut row = Row::UNKNOWN;
    for (k, r) in records.iter().enumerate().take(start as usize) {
        robot.tick(k as u64, r.x_meas, r.xdot_meas, &mut row);
    }
    let measured: Vec<(f64, f64)> = records[start as usize..end as usize]
        .iter()
        .map(|r| (r.x_meas, r.xdot_meas))
        .collect();
    let samples: Vec<_> = (start..end)
        .map(|k| protocol.sample(k).expect("tick inside the protocol"))
        .collect();
    assert!(samples.iter().all(|s| s.index == phase));
    let mut i = 0usize;
    Box::new(move || {
        robot.tick_at(black_box(&samples[i]), Some(measured[i]), &mut row);
        black_box(&row);
        i += 1;
        if i == samples.len() {
            i = 0;
        }
    })
}

/// The gain phase's tick (stage 1 and its window, LQR command).
pub fn robot_tick_gains() -> Call {
    robot_tick(0)
}

/// The trajectory phase's tick (stage 2).
pub fn robot_tick_trajectory() -> Call {
    robot_tick(1)
}

/// The integration phase's tick (stage 2, both stage-3 filters, noisy
/// target view).
pub fn robot_tick_integration() -> Call {
    robot_tick(2)
}

/// The robot with `robot.partner_delay = "auto"` (docs/model.md, "A partner
/// with a delay").
fn delay_aware_robot() -> sensaug_core::controller::RobotConfig {
    sensaug_core::controller::RobotConfig {
        partner_delay: sensaug_core::identifier::PartnerDelay::Auto,
        ..common::robot()
    }
}

/// The gain phase's tick with the delay search (its coarse grid for the
/// first 30% of the phase, the fine one after: the timed ticks wrap round
/// the whole phase, so both are in the figures) and the delay-aware stage 1.
pub fn robot_tick_gains_delay_auto() -> Call {
    robot_tick_with(0, delay_aware_robot())
}

/// The trajectory phase's tick with the delay-aware stage 2.
pub fn robot_tick_trajectory_delay_auto() -> Call {
    robot_tick_with(1, delay_aware_robot())
}

/// The robot-tick workloads, one per phase, then the delay-aware robot's.
pub const TICK_WORKLOADS: [Workload; 5] = [
    ("robot_tick/gains_phase", robot_tick_gains),
    ("robot_tick/trajectory_phase", robot_tick_trajectory),
    ("robot_tick/integration_phase", robot_tick_integration),
    (
        "robot_tick/gains_phase_delay_auto",
        robot_tick_gains_delay_auto,
    ),
    (
        "robot_tick/trajectory_phase_delay_auto",
        robot_tick_trajectory_delay_auto,
    ),
];

/// Phase length of the whole-trial workload (s), as
/// `presets.hi5_experiment(phase_s=20.0)` timed from Python by
/// `benches/compare_oracles.py` (`sensaug_trial_per_tick_ns`).
pub const TRIAL_PHASE_S: f64 = 20.0;

/// The whole simulated trial of `presets.hi5_experiment(phase_s=20.0)` (seed
/// 0: world seed 0, robot seed 1_000_003; a virtual human that does not
/// identify the robot) through the core's runner, without Python: one call
/// is one whole trial into a buffer allocated at set-up. Returns the call
/// and the ticks per call.
pub fn trial() -> (Call, usize) {
    let phases = common::phases(TRIAL_PHASE_S, 1.0);
    let robot = sensaug_core::controller::RobotConfig {
        seed: 1_000_003,
        ..common::robot()
    };
    let partner = sensaug_core::world::PartnerConfig {
        estimates_robot: false,
        ..common::partner(2.0)
    };
    let make = move || Scenario::new(&phases, robot, partner, common::world(0));
    let ticks = make().expect("valid scenario").ticks();
    let mut records = vec![Row::UNKNOWN; ticks];
    let call = Box::new(move || {
        let mut scenario = make().expect("valid scenario");
        let summary = scenario.run(black_box(&mut records)).expect("whole trial");
        black_box(summary);
    });
    (call, ticks)
}

/// Every workload by name (the names of the criterion benches and of the
/// rows of `BENCHMARKS.md`).
pub fn all() -> [Workload; 12] {
    [
        ("ukf_step/6_states_3_measurements", ukf_step_3),
        ("ukf_step/6_states_5_measurements", ukf_step_5),
        ("goal_integrator/8_members", goal_integrator_step),
        ("care/2_states", care_2),
        ("care/3_states", care_3),
        ("dare/2_states", dare_2),
        ("dare/3_states", dare_3),
        TICK_WORKLOADS[0],
        TICK_WORKLOADS[1],
        TICK_WORKLOADS[2],
        TICK_WORKLOADS[3],
        TICK_WORKLOADS[4],
    ]
}
