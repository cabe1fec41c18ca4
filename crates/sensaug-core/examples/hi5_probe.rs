//! Scratch probe: runs the Hi5 protocol once and prints the headline metrics.
use nalgebra::{SMatrix, SVector, Vector2};
use sensaug_core::estimator::{ExtendedFilterConfig, GoalIntegratorConfig, HandleModel};
use sensaug_core::plant::{PlantParams, PlantState};
use sensaug_core::scenario::*;
use sensaug_core::target::{Shape, Target};
use sensaug_core::ukf::MerweParams;

fn main() {
    let args: Vec<f64> = std::env::args()
        .skip(1)
        .map(|a| a.parse().unwrap())
        .collect();
    let lhh = args.first().copied().unwrap_or(2.0);
    let noise = args.get(1).copied().unwrap_or(1.0);
    let motor = args.get(2).copied().unwrap_or(1e-3);
    let seed = args.get(3).copied().unwrap_or(1.0) as u64;
    let chirp_amp = args.get(4).copied().unwrap_or(2.0);
    let window = args.get(5).copied().unwrap_or(0.05);
    let q3 = args.get(6).copied().unwrap_or(1e-2);
    let m = 0.0035;
    let dt = 1e-3;
    let rs = Shape::RoundedSquare {
        amplitude: 8.0,
        period_s: 4.0,
    };
    let chirp = Shape::Chirp {
        amplitude: chirp_amp,
        f0_hz: 0.0,
        f1_hz: 2.0,
        duration_s: 20.0,
    };
    let same = Target::single(rs);
    let phases = [
        Phase {
            kind: PhaseKind::Gains,
            duration_s: 20.0,
            robot_target: same.plus(chirp).unwrap(),
            partner_target: same,
            target_noise_std: 0.0,
        },
        Phase {
            kind: PhaseKind::Trajectory,
            duration_s: 20.0,
            robot_target: same,
            partner_target: same,
            target_noise_std: 0.0,
        },
        Phase {
            kind: PhaseKind::Integration,
            duration_s: 20.0,
            robot_target: same,
            partner_target: same,
            target_noise_std: noise,
        },
    ];
    let sigma = MerweParams {
        alpha: 1.0,
        beta: 2.0,
        kappa: 0.0,
    };
    let mut P0 = SMatrix::<f64, 6, 6>::identity();
    for i in 0..3 {
        P0[(i, i)] = 1e-4;
    }
    let x0 = SVector::<f64, 6>::zeros();
    let model = HandleModel {
        mass: m,
        damping: 0.0,
        dt_s: dt,
    };
    let robot = RobotConfig {
        gains: [1.0, (2.0 * m).sqrt(), 0.0],
        model,
        stage1: ExtendedFilterConfig {
            x0,
            P0,
            Q: SMatrix::identity() * 1e-2,
            R: SMatrix::identity() * 1e-7,
            sigma,
        },
        stage2: ExtendedFilterConfig {
            x0,
            P0,
            Q: SMatrix::identity() * 1e-2,
            R: SMatrix::identity() * 1e-7,
            sigma,
        },
        stage3: GoalIntegratorConfig {
            x0: Vector2::zeros(),
            P0: SMatrix::identity() * 1e-2,
            Q: SMatrix::<f64, 2, 2>::identity() * q3,
            R_own: SMatrix::<f64, 2, 2>::from_diagonal(&Vector2::new(1e-7, 1e-7)),
            partner_window_s: window,
            sigma,
        },
        integrate: true,
        gain_window_s: 8.0,
        prior_partner_gains: None,
        torque_limit: 1e3,
        seed: seed + 100,
    };
    let partner = PartnerConfig {
        gains: [0.0, 0.0, lhh],
        torque_limit: 1e3,
        estimates_robot: false,
    };
    let world = WorldConfig {
        plant: PlantParams {
            mass: m,
            damping: 0.0,
            coulomb: 0.0,
            dt_s: dt,
        },
        initial: PlantState::default(),
        motor_noise_std: motor,
        position_noise_std: 1e-7f64.sqrt(),
        velocity_noise_std: 1e-7f64.sqrt(),
        seed,
    };
    let mut sc = Scenario::new(&phases, robot, partner, world).unwrap();
    let mut out = vec![TickRecord::default(); sc.ticks()];
    let t0 = std::time::Instant::now();
    let summary = sc.run(&mut out).unwrap();
    println!("run {:?} {:?}", t0.elapsed(), summary);
    let p1: Vec<_> = out
        .iter()
        .filter(|r| r.phase == 0.0 && r.t >= 12.0)
        .collect();
    let mean = |f: &dyn Fn(&TickRecord) -> f64, v: &[&TickRecord]| {
        v.iter().map(|r| f(r)).sum::<f64>() / v.len() as f64
    };
    println!(
        "gains last 8s: {:.4} {:.4} {:.4} (true 0 0 {lhh})",
        mean(&|r| r.L_hat[0], &p1),
        mean(&|r| r.L_hat[1], &p1),
        mean(&|r| r.L_hat[2], &p1)
    );
    let p2: Vec<_> = out
        .iter()
        .filter(|r| r.phase == 1.0 && r.t >= 22.0)
        .collect();
    let rmse2 = mean(&|r| (r.tau_h_hat - r.tau_h).powi(2), &p2).sqrt();
    println!("tau_h rmse {:.4} ({:.2}% of 8)", rmse2, rmse2 / 8.0 * 100.0);
    let p3: Vec<_> = out
        .iter()
        .filter(|r| r.phase == 2.0 && r.t >= 42.0)
        .collect();
    let own = mean(&|r| (r.e_hat_own - r.e).powi(2), &p3).sqrt();
    let fused = mean(&|r| (r.e_hat_fused - r.e).powi(2), &p3).sqrt();
    let raw = mean(&|r| (r.e_meas - r.e).powi(2), &p3).sqrt();
    let track = mean(&|r| r.e.powi(2), &p3).sqrt();
    println!("stage3 rmse raw {raw:.4} own {own:.4} fused {fused:.4} ratio {:.2}; tracking rmse {track:.4}; pv mean {:.2e}", own / fused, mean(&|r| r.partner_var, &p3));
}
