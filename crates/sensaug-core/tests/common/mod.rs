//! The Hi5 protocol of the paper, built in Rust for the integration tests and
//! the benches (same numbers as `python/sensaug/presets.py::hi5_experiment`).
#![allow(dead_code)]
use nalgebra::{SMatrix, SVector, Vector2};
use sensaug_core::controller::RobotConfig;
use sensaug_core::estimator::{ExtendedFilterConfig, HandleModel};
use sensaug_core::estimator::{GainEstimator, TrajectoryEstimator};
use sensaug_core::goal::{ChannelConfig, GoalIntegrator, GoalIntegratorConfig};
use sensaug_core::plant::{PlantParams, PlantState};
use sensaug_core::protocol::{Phase, PhaseKind};
use sensaug_core::target::{Shape, Target};
use sensaug_core::ukf::MerweParams;
use sensaug_core::world::{PartnerConfig, StateSource, WorldConfig};

pub const M: f64 = PlantParams::HI5.mass;
pub const DT: f64 = PlantParams::HI5.dt_s;

pub fn phases(phase_s: f64, noise: f64) -> [Phase<'static>; 3] {
    let rs = Target::single(Shape::RoundedSquare {
        amplitude: 8.0,
        period_s: 4.0,
    });
    let chirp = Shape::Chirp {
        amplitude: 2.0,
        f0_hz: 0.0,
        f1_hz: 2.0,
        duration_s: phase_s,
    };
    let phase = |kind, robot_target, target_noise_std| Phase {
        kind,
        duration_s: phase_s,
        robot_target,
        partner_target: rs,
        target_noise_std,
    };
    [
        phase(PhaseKind::Gains, rs.plus(chirp).unwrap(), 0.0),
        phase(PhaseKind::Trajectory, rs, 0.0),
        phase(PhaseKind::Integration, rs, noise),
    ]
}

pub fn extended<const R: usize>() -> ExtendedFilterConfig<R> {
    let mut P0 = SMatrix::<f64, 6, 6>::identity();
    for i in 0..3 {
        P0[(i, i)] = 1e-4;
    }
    ExtendedFilterConfig {
        x0: SVector::zeros(),
        P0,
        Q: SMatrix::identity() * 1e-2,
        R: SMatrix::identity() * 1e-7,
        sigma: MerweParams {
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
        },
    }
}

pub fn model() -> HandleModel {
    HandleModel {
        mass: M,
        damping: 0.0,
        dt_s: DT,
    }
}

/// The three estimators on [`model`]: stage 1 and 2 with [`extended`],
/// stage 3 as [`robot`] configures it.
pub fn estimators() -> (GainEstimator, TrajectoryEstimator, GoalIntegrator) {
    (
        GainEstimator::new(model(), &extended::<3>()).unwrap(),
        TrajectoryEstimator::new(model(), &extended::<5>()).unwrap(),
        GoalIntegrator::new(model(), &robot().stage3).unwrap(),
    )
}

pub fn robot() -> RobotConfig {
    RobotConfig {
        gains: [1.0, (2.0 * M).sqrt(), 0.0],
        model: model(),
        stage1: extended(),
        stage2: extended(),
        stage3: GoalIntegratorConfig {
            x0: Vector2::zeros(),
            P0: SMatrix::identity() * 1e-2,
            Q: SMatrix::identity() * 1e-2,
            R_own: SMatrix::identity() * 1e-7,
            channel: ChannelConfig::default(),
        },
        integrate: true,
        gain_window_s: 8.0,
        prior_partner_gains: None,
        torque_limit: 1e3,
        seed: 7,
        partner_delay: sensaug_core::identifier::PartnerDelay::Paper,
    }
}

pub fn partner(lhh: f64) -> PartnerConfig {
    PartnerConfig {
        gains: [0.0, 0.0, lhh],
        torque_limit: 1e3,
        estimates_robot: true,
        acts_on: StateSource::Measured,
        human: None,
        integration: None,
    }
}

pub fn world(seed: u64) -> WorldConfig {
    WorldConfig {
        plant: PlantParams::HI5,
        initial: PlantState::default(),
        motor_noise_std: 1e-3,
        position_noise_std: 1e-7f64.sqrt(),
        velocity_noise_std: 1e-7f64.sqrt(),
        seed,
    }
}
