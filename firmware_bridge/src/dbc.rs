//! The tables of `hi5.dbc`, generated at build time (`build.rs`, parsed with
//! the `can-dbc` crate): one module per message holding its [`MessageDef`]
//! and one [`SignalDef`] per signal, the node addressing
//! ([`LISTED_NODE`], [`NODE_COUNT`]), the `VAL_` names of the `state` and
//! `request` signals and the fault bits of `fault_flags`.
//!
//! The codec ([`crate::protocol`]) reads ids, DLCs, bit positions, scales
//! and ranges only from here, so editing the DBC changes the codec; a
//! renamed or removed message or signal fails to compile. The generic bit
//! access ([`SignalDef::get`], [`SignalDef::put`]) handles Intel
//! (little-endian) signals of up to 32 bits, all the build script accepts.

/// One message of the DBC.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MessageDef {
    /// The DBC's message name.
    pub name: &'static str,
    /// Node 0's id: the DBC id minus [`LISTED_NODE`]; node `n` uses
    /// `base_id + n`.
    pub base_id: u32,
    /// Data length code.
    pub dlc: u8,
    /// Sending node (`HOST` or `HI5`).
    pub sender: &'static str,
    /// The payload bits (bit `i` = bit `i % 8` of byte `i / 8`) some signal
    /// covers.
    pub signal_bits: u64,
}

impl MessageDef {
    /// The payload bits within the DLC that no signal covers.
    pub const fn unused_bits(&self) -> u64 {
        let within_dlc = if self.dlc >= 8 {
            u64::MAX
        } else {
            (1u64 << (8 * self.dlc as u32)) - 1
        };
        within_dlc & !self.signal_bits
    }
}

/// One signal of the DBC: Intel byte order, `bits` long from `start_bit`.
///
/// Physical value = `raw x scale + offset`, allowed in `[min, max]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignalDef {
    /// `Message.signal`, as in the DBC (names errors).
    pub name: &'static str,
    /// Lowest bit (bit `i` = bit `i % 8` of byte `i / 8`).
    pub start_bit: u8,
    /// Length in bits, 1..=32.
    pub bits: u8,
    /// Two's complement (`-`) or unsigned (`+`).
    pub signed: bool,
    /// Physical units per LSB.
    pub scale: f64,
    /// Physical value of raw 0.
    pub offset: f64,
    /// Smallest physical value allowed.
    pub min: f64,
    /// Largest physical value allowed.
    pub max: f64,
    /// Unit, as in the DBC.
    pub unit: &'static str,
}

impl SignalDef {
    /// The smallest and largest raw integer the field holds.
    pub const fn raw_range(&self) -> (i64, i64) {
        let n = self.bits as u32;
        if self.signed {
            (-(1i64 << (n - 1)), (1i64 << (n - 1)) - 1)
        } else {
            (0, (1i64 << n) - 1)
        }
    }

    /// True if the signal is an unsigned field exactly `bits` wide (for the
    /// compile-time checks that a Rust field type holds it).
    pub const fn is_unsigned(&self, bits: u8) -> bool {
        !self.signed && self.bits == bits
    }

    /// The raw field of `data`, sign-extended if signed.
    pub fn get(&self, data: &[u8; 8]) -> i64 {
        let word = u64::from_le_bytes(*data) >> self.start_bit;
        let n = u32::from(self.bits);
        let field = word & (u64::MAX >> (64 - n));
        if self.signed {
            // Shift the sign bit to bit 63 and back arithmetically.
            ((field << (64 - n)) as i64) >> (64 - n)
        } else {
            field as i64
        }
    }

    /// Write the low `bits` bits of `raw` into the field of `data`; other
    /// bits are kept. `raw` must be in [`SignalDef::raw_range`] (the
    /// encoder checks before).
    pub fn put(&self, data: &mut [u8; 8], raw: i64) {
        let n = u32::from(self.bits);
        let mask = (u64::MAX >> (64 - n)) << self.start_bit;
        let word = u64::from_le_bytes(*data) & !mask | ((raw as u64) << self.start_bit) & mask;
        *data = word.to_le_bytes();
    }

    /// Physical value of `raw`: `raw x scale + offset`.
    pub fn physical(&self, raw: i64) -> f64 {
        raw as f64 * self.scale + self.offset
    }
}

include!(concat!(env!("OUT_DIR"), "/hi5_dbc.rs"));

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::MessageKind;

    #[test]
    fn message_kinds_are_the_dbc_messages_in_id_order() {
        let defs: Vec<MessageDef> = MessageKind::ALL.iter().map(|k| *k.def()).collect();
        assert_eq!(defs, MESSAGES.to_vec());
        assert!(MESSAGES.windows(2).all(|w| w[0].base_id < w[1].base_id));
    }

    #[test]
    fn get_put_round_trip_signed_and_unsigned_fields() {
        let sig = |start_bit, bits, signed| SignalDef {
            name: "T.s",
            start_bit,
            bits,
            signed,
            scale: 1.0,
            offset: 0.0,
            min: 0.0,
            max: 0.0,
            unit: "",
        };
        for (start, bits) in [
            (0, 1),
            (3, 2),
            (7, 9),
            (24, 24),
            (32, 32),
            (56, 8),
            (40, 24),
        ] {
            for signed in [false, true] {
                let s = sig(start, bits, signed);
                let (lo, hi) = s.raw_range();
                for raw in [lo, lo + 1, 0, hi - 1, hi] {
                    let mut d = [0xA5u8; 8];
                    let before = u64::from_le_bytes(d);
                    s.put(&mut d, raw);
                    assert_eq!(s.get(&d), raw, "start {start} bits {bits} signed {signed}");
                    let mask = (u64::MAX >> (64 - u32::from(bits))) << start;
                    // Bits outside the field are untouched.
                    assert_eq!(u64::from_le_bytes(d) & !mask, before & !mask);
                }
            }
        }
        assert_eq!(sig(0, 24, true).raw_range(), (-(1 << 23), (1 << 23) - 1));
        assert_eq!(sig(0, 16, false).raw_range(), (0, 65535));
    }

    #[test]
    fn unused_bits_are_the_gaps_within_the_dlc() {
        // TorqueCommand: byte 5 is not covered by a signal.
        assert_eq!(torque_command::MESSAGE.unused_bits(), 0x0000_FF00_0000_0000);
        assert_eq!(set_state::MESSAGE.unused_bits(), 0);
        // Feedback: bits 4..8 of byte 7.
        assert_eq!(feedback::MESSAGE.unused_bits(), 0xF000_0000_0000_0000);
        assert_eq!(emergency_stop::MESSAGE.unused_bits(), 0);
    }
}
