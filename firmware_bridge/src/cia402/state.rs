//! The CiA 402 power drive state machine, seen from the master: decode the
//! statusword 0x6041, choose the controlword 0x6040.
//!
//! ```text
//!  NotReadyToSwitchOn ─(auto)─► SwitchOnDisabled ◄─────── DisableVoltage ─────┐
//!                                 │ ▲       ▲                                  │
//!                        Shutdown │ │ Disable voltage / QuickStop             │
//!                                 ▼ │       │                                  │
//!                           ReadyToSwitchOn ─┘                          QuickStopActive
//!                                 │ ▲                                          ▲
//!                        SwitchOn │ │ Shutdown                       QuickStop │
//!                                 ▼ │                                          │
//!                             SwitchedOn ──EnableOperation──► OperationEnabled ┘
//!  any ─(fault)─► FaultReactionActive ─► Fault ─(FaultReset, rising edge)─► SwitchOnDisabled
//! ```

use super::Cia402Error;

/// A drive state, decoded from the statusword (CiA 402 table 30).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveState {
    /// `xxxx xxxx x0xx 0000`.
    NotReadyToSwitchOn,
    /// `xxxx xxxx x1xx 0000`.
    SwitchOnDisabled,
    /// `xxxx xxxx x01x 0001`.
    ReadyToSwitchOn,
    /// `xxxx xxxx x01x 0011`.
    SwitchedOn,
    /// `xxxx xxxx x01x 0111`: torque follows the target.
    OperationEnabled,
    /// `xxxx xxxx x00x 0111`.
    QuickStopActive,
    /// `xxxx xxxx x0xx 1111`.
    FaultReactionActive,
    /// `xxxx xxxx x0xx 1000`.
    Fault,
}

/// Statusword bit 11: internal limit active (the virtual drive sets it for
/// a cycle whose target torque it rejected).
pub const STATUS_INTERNAL_LIMIT: u16 = 1 << 11;
/// Statusword bit 7: warning.
pub const STATUS_WARNING: u16 = 1 << 7;

/// Decodes the state bits 0-3, 5 and 6 of `statusword`.
pub fn decode_statusword(statusword: u16) -> Result<DriveState, Cia402Error> {
    // (mask, value, state), CiA 402 table 30.
    const TABLE: [(u16, u16, DriveState); 8] = [
        (0x4F, 0x00, DriveState::NotReadyToSwitchOn),
        (0x4F, 0x40, DriveState::SwitchOnDisabled),
        (0x6F, 0x21, DriveState::ReadyToSwitchOn),
        (0x6F, 0x23, DriveState::SwitchedOn),
        (0x6F, 0x27, DriveState::OperationEnabled),
        (0x6F, 0x07, DriveState::QuickStopActive),
        (0x4F, 0x0F, DriveState::FaultReactionActive),
        (0x4F, 0x08, DriveState::Fault),
    ];
    TABLE
        .iter()
        .find(|(mask, value, _)| statusword & mask == *value)
        .map(|&(_, _, s)| s)
        .ok_or(Cia402Error::InvalidValue {
            field: "statusword",
            raw: u32::from(statusword),
        })
}

/// Controlword commands (CiA 402 table 28; bits 0-3 and 7).
pub mod controlword {
    /// Shutdown: `0xxx x110` (to ReadyToSwitchOn).
    pub const SHUTDOWN: u16 = 0x0006;
    /// Switch on / disable operation: `0xxx 0111` (to SwitchedOn).
    pub const SWITCH_ON: u16 = 0x0007;
    /// Enable operation: `0xxx 1111` (to OperationEnabled).
    pub const ENABLE_OPERATION: u16 = 0x000F;
    /// Disable voltage: `0xxx xx0x` (to SwitchOnDisabled).
    pub const DISABLE_VOLTAGE: u16 = 0x0000;
    /// Quick stop: `0xxx x01x` (to QuickStopActive, torque 0 at once).
    pub const QUICK_STOP: u16 = 0x0002;
    /// Fault reset: bit 7, acted on at its rising edge.
    pub const FAULT_RESET: u16 = 0x0080;
}

/// What the master wants the drive to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Goal {
    /// Reach OperationEnabled; in Fault, reset it (rising edge of bit 7).
    Enabled,
    /// Torque off, stay powered: ReadyToSwitchOn.
    Disabled,
    /// Quick stop: torque 0 now.
    QuickStop,
}

/// The controlword that moves a drive in `state` one transition towards
/// `goal`. `previous` is the controlword sent last: a fault reset needs a
/// rising edge of bit 7, so after sending it once the next call sends 0.
pub fn next_controlword(state: DriveState, goal: Goal, previous: u16) -> u16 {
    use controlword::*;
    match goal {
        Goal::QuickStop => QUICK_STOP,
        Goal::Disabled => match state {
            DriveState::Fault | DriveState::FaultReactionActive => DISABLE_VOLTAGE,
            DriveState::QuickStopActive => DISABLE_VOLTAGE,
            _ => SHUTDOWN,
        },
        Goal::Enabled => match state {
            DriveState::Fault => {
                if previous & FAULT_RESET != 0 {
                    DISABLE_VOLTAGE
                } else {
                    FAULT_RESET
                }
            }
            DriveState::FaultReactionActive | DriveState::NotReadyToSwitchOn => DISABLE_VOLTAGE,
            // Leaving quick stop goes through SwitchOnDisabled.
            DriveState::QuickStopActive => DISABLE_VOLTAGE,
            DriveState::SwitchOnDisabled => SHUTDOWN,
            DriveState::ReadyToSwitchOn => SWITCH_ON,
            DriveState::SwitchedOn | DriveState::OperationEnabled => ENABLE_OPERATION,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statuswords_of_every_state() {
        let cases = [
            (0x0000, DriveState::NotReadyToSwitchOn),
            (0x0240, DriveState::SwitchOnDisabled),
            (0x0231, DriveState::ReadyToSwitchOn),
            (0x0233, DriveState::SwitchedOn),
            (0x0237, DriveState::OperationEnabled),
            (0x0A37, DriveState::OperationEnabled),
            (0x0217, DriveState::QuickStopActive),
            (0x021F, DriveState::FaultReactionActive),
            (0x0208, DriveState::Fault),
            (0x0218, DriveState::Fault),
        ];
        for (sw, s) in cases {
            assert_eq!(decode_statusword(sw).unwrap(), s, "{sw:#06x}");
        }
        assert!(decode_statusword(0x0001).is_err());
    }

    #[test]
    fn enabling_walks_the_transitions_and_resets_a_fault_on_an_edge() {
        use controlword::*;
        use DriveState::*;
        // (state, goal, previous controlword, the next controlword)
        let cases = [
            (Fault, Goal::Enabled, 0, FAULT_RESET),
            (Fault, Goal::Enabled, FAULT_RESET, 0),
            (SwitchOnDisabled, Goal::Enabled, 0, SHUTDOWN),
            (ReadyToSwitchOn, Goal::Enabled, 6, SWITCH_ON),
            (SwitchedOn, Goal::Enabled, 7, ENABLE_OPERATION),
            (OperationEnabled, Goal::Enabled, 15, ENABLE_OPERATION),
            (OperationEnabled, Goal::Disabled, 15, SHUTDOWN),
            (OperationEnabled, Goal::QuickStop, 15, QUICK_STOP),
        ];
        for (state, goal, previous, next) in cases {
            assert_eq!(
                next_controlword(state, goal, previous),
                next,
                "{state:?} towards {goal:?} after {previous:#06x}"
            );
        }
    }
}
