//! The torque the estimators and the log see (`applied_torque`) is the
//! torque the drive applies: the same number as the CiA 402 master's
//! per-mille (`Units::torque_to_per_mille`) and the Hi5 DBC encoder's raw
//! value (`protocol::encode`) times their steps, for commands on, between and
//! half-way between the steps, of both signs.

use sensaug_bridge::cia402::Units;
use sensaug_bridge::protocol::{decode, encode, Message, NodeId, TORQUE_SCALE_NM};
use sensaug_core::controller::applied_torque;

/// Commands from -0.1 to 0.1 N m in steps of 0.0137 mN m (not a multiple of
/// either resolution) and the exact half-steps of both.
fn commands(step: f64) -> Vec<f64> {
    let mut out: Vec<f64> = (-7300..=7300).map(|i| f64::from(i) * 1.37e-5).collect();
    out.extend((-200..=200).map(|i| (f64::from(i) + 0.5) * step));
    out
}

#[test]
fn cia402_applied_torque_is_the_per_mille_the_master_sends() {
    for rated_mnm in [1000, 100, 37] {
        let units = Units::new(rated_mnm, 3000, (1 << 20, 1), (1, 1)).unwrap();
        let step = units.torque_step_nm();
        let limit = units.max_torque_nm();
        for t in commands(step) {
            let sent = f64::from(units.torque_to_per_mille(t).unwrap()) * step;
            assert_eq!(
                applied_torque(t, step, limit),
                sent,
                "{t} N m, rated {rated_mnm} mN m"
            );
        }
    }
}

#[test]
fn hi5_applied_torque_is_the_raw_value_the_dbc_encodes() {
    for t in commands(TORQUE_SCALE_NM) {
        let node = NodeId::new(1).unwrap();
        let msg = Message::TorqueCommand {
            torque_nm: t,
            sequence: 0,
        };
        let Message::TorqueCommand {
            torque_nm: sent, ..
        } = decode(node, &encode(node, &msg).unwrap()).unwrap()
        else {
            panic!("not a TorqueCommand");
        };
        assert_eq!(applied_torque(t, TORQUE_SCALE_NM, 3.0), sent, "{t} N m");
    }
}

#[test]
fn a_command_at_the_limit_stays_within_it() {
    // 2.9996 rounds up to 3.000 at 1 mN m steps; a limit of 2.9996 takes it one step back.
    assert_eq!(applied_torque(2.9996, 1e-3, 2.9996), 2.999);
    assert_eq!(applied_torque(-2.9996, 1e-3, 2.9996), -2.999);
    assert_eq!(applied_torque(0.123_456, f64::NAN, 3.0), 0.123_456);
}
