//! The one log row of sensaug: every column once (name, unit, kind, who
//! fills it, a one-line description) in one table, from which [`Row`] (one
//! tick), [`PackedRow`] (its numpy record) and [`COLUMNS`] are generated.
//!
//! The simulation ([`crate::world`]) and the rig loop fill a [`Row`]
//! directly: the controller ([`crate::controller::Robot::tick_at`]) writes
//! the [`ColumnSource::Controller`] columns, the world (plant, sensors,
//! partner; on the rig: the drive's feedback, the targets, the virtual
//! human) the [`ColumnSource::World`] ones, the rig loop the
//! [`ColumnSource::Rig`] ones; a column nobody fills stays unknown (NaN,
//! [`UNKNOWN`], `false`). A replay recomputes exactly the controller's
//! columns ([`Row::copy_columns`]). The file format and the metadata live in
//! `sensaug-log`.

/// The value of an integer column that one side cannot know.
pub const UNKNOWN: i64 = -1;

/// Who fills a column (see the module's doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColumnSource {
    /// The tick's number and time: whoever runs the ticks.
    Time,
    /// The robot's controller; a replay recomputes these.
    Controller,
    /// The handle, the measurement, the targets and the partner: the
    /// simulated world, or on the rig the drive's feedback and the loop's
    /// protocol and virtual human. Some are simulation-only (NaN on the rig).
    World,
    /// The rig loop only (unknown in simulations).
    Rig,
}

impl ColumnSource {
    /// The name used by the Python schema (`sensaug.logs`).
    pub fn name(self) -> &'static str {
        match self {
            ColumnSource::Time => "time",
            ColumnSource::Controller => "controller",
            ColumnSource::World => "world",
            ColumnSource::Rig => "rig",
        }
    }
}

/// What a column holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A signed 64-bit integer; [`UNKNOWN`] where not known.
    Int,
    /// A 64-bit float; NaN where not known.
    Float,
    /// A boolean, written `0` or `1`.
    Bool,
}

impl Kind {
    /// The name used in the metadata and by the Python loader.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Int => "int",
            Kind::Float => "float",
            Kind::Bool => "bool",
        }
    }
}

/// One column of the schema.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Column {
    /// Header name.
    pub name: &'static str,
    /// Unit (symbols defined in [`UNITS`]).
    pub unit: &'static str,
    /// Integer, float or boolean.
    pub kind: Kind,
    /// Who fills it.
    pub source: ColumnSource,
    /// One line: what it is, and which side leaves it unknown.
    pub description: &'static str,
}

/// One value of a row, as the file and the packed record hold it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// An integer column.
    Int(i64),
    /// A float column.
    Float(f64),
    /// A boolean column.
    Bool(bool),
}

/// A value that does not fit its column ([`Row::set`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColumnError {
    /// The value has another kind, or is not one of the column's codes.
    Invalid {
        /// The column.
        column: &'static str,
        /// Its kind.
        expected: Kind,
        /// The value given.
        got: Value,
    },
    /// No column at this index.
    NoColumn {
        /// The index given.
        index: usize,
    },
}

impl core::fmt::Display for ColumnError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ColumnError::Invalid {
                column,
                expected,
                got,
            } => write!(f, "{column}: expected {}, got {got:?}", expected.name()),
            ColumnError::NoColumn { index } => {
                write!(f, "column index {index} >= {}", COLUMNS.len())
            }
        }
    }
}

/// A Rust type a column holds, with its file value and its packed record.
pub trait Cell: Copy {
    /// The column's kind in the file.
    const KIND: Kind;
    /// Not known.
    const UNKNOWN: Self;
    /// The value in the file.
    fn value(self) -> Value;
    /// From a value in the file (`None`: wrong kind or not a valid code).
    fn from_value(value: Value) -> Option<Self>;
    /// Its field of the packed record.
    type Packed: Copy;
    /// The packed field.
    fn pack(self) -> Self::Packed;
}

/// A plain column: the value itself, in the file and in the record.
macro_rules! plain_cell {
    ($($ty:ty => $kind:ident, $unknown:expr;)*) => {$(
        impl Cell for $ty {
            const KIND: Kind = Kind::$kind;
            const UNKNOWN: Self = $unknown;
            fn value(self) -> Value {
                Value::$kind(self)
            }
            fn from_value(value: Value) -> Option<Self> {
                match value {
                    Value::$kind(v) => Some(v),
                    _ => None,
                }
            }
            type Packed = $ty;
            fn pack(self) -> $ty {
                self
            }
        }
    )*};
}

plain_cell! {
    i64 => Int, UNKNOWN;
    f64 => Float, f64::NAN;
    bool => Bool, false;
}

/// The phase column: its kind's code ([`PhaseKind::code`]), [`UNKNOWN`]
/// outside the protocol (`None`).
impl Cell for Option<PhaseKind> {
    const KIND: Kind = Kind::Int;
    const UNKNOWN: Self = None;
    fn value(self) -> Value {
        Value::Int(self.map_or(UNKNOWN, PhaseKind::code))
    }
    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::Int(UNKNOWN) => Some(None),
            Value::Int(code) => PhaseKind::from_code(code).map(Some),
            _ => None,
        }
    }
    type Packed = i64;
    fn pack(self) -> i64 {
        self.map_or(UNKNOWN, PhaseKind::code)
    }
}

/// The guard column: 0 passed, 1 clamped, 2 non-finite; [`UNKNOWN`] when
/// no guard ran (`None`: the controlled stop, simulations).
impl Cell for Option<Guard> {
    const KIND: Kind = Kind::Int;
    const UNKNOWN: Self = None;
    fn value(self) -> Value {
        Value::Int(match self {
            None => UNKNOWN,
            Some(Guard::Passed) => 0,
            Some(Guard::Clamped) => 1,
            Some(Guard::NonFinite) => 2,
        })
    }
    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::Int(UNKNOWN) => Some(None),
            Value::Int(0) => Some(Some(Guard::Passed)),
            Value::Int(1) => Some(Some(Guard::Clamped)),
            Value::Int(2) => Some(Some(Guard::NonFinite)),
            _ => None,
        }
    }
    type Packed = i64;
    fn pack(self) -> i64 {
        match self.value() {
            Value::Int(v) => v,
            _ => UNKNOWN,
        }
    }
}

/// The unit symbols used in [`COLUMNS`]; `u^2` and `(u)^2` are squares of `u`
/// (variances).
pub const UNITS: [(&str, &str); 11] = [
    ("1", "dimensionless count or code"),
    ("s", "second"),
    ("ms", "millisecond"),
    ("us", "microsecond"),
    ("nats", "natural-log units of a log-likelihood"),
    ("pos", "controller position unit: rig.position_unit on the rig (rad_per_unit rad), deg in the Hi5 presets"),
    ("pos/s", "controller position unit per second"),
    ("trq", "model torque unit: the robot's torque in the handle model (on the rig, N m = trq * rad_per_unit)"),
    ("N m", "newton metre at the drive"),
    ("trq/pos", "position gain (Lhx, Lhh, Lx, Lh)"),
    ("trq s/pos", "velocity gain (Lhv, Lv)"),
];

macro_rules! schema {
    ($( $name:ident : $ty:ty => $packed:ty, $unit:literal, $source:ident, $doc:literal; )*) => {
        /// One tick of a log, one field per column of [`COLUMNS`] (same
        /// order), filled directly by the simulation and the rig loop.
        #[derive(Clone, Copy, Debug, PartialEq)]
        pub struct Row {
            $( #[doc = $doc] pub $name: $ty, )*
        }

        /// A [`Row`] as one packed record, the layout of the Python log's
        /// structured array (`sensaug.logs.DTYPE`): the columns in
        /// [`COLUMNS`] order, native-endian, no padding, a bool as one
        /// byte, a code as its `i64`. Its bytes are a record
        /// ([`Row::packed`], `as_bytes`).
        #[derive(Clone, Copy, Debug, zerocopy::IntoBytes, zerocopy::TryFromBytes)]
        #[derive(zerocopy::Immutable, zerocopy::KnownLayout)]
        #[repr(C, packed)]
        pub struct PackedRow {
            $( #[doc = $doc] pub $name: $packed, )*
        }

        /// Every column of a log, in file order.
        pub const COLUMNS: [Column; schema!(@count $($name)*)] = [
            $( Column {
                name: stringify!($name),
                unit: $unit,
                kind: <$ty as Cell>::KIND,
                source: ColumnSource::$source,
                description: $doc,
            }, )*
        ];

        impl Row {
            /// Nothing known: NaN floats, [`UNKNOWN`] integers and codes, `false`.
            pub const UNKNOWN: Row = Row { $( $name: <$ty as Cell>::UNKNOWN, )* };

            /// The row as a packed record ([`PackedRow`]).
            pub fn packed(&self) -> PackedRow {
                PackedRow { $( $name: Cell::pack(self.$name), )* }
            }

            /// The row a packed record holds; the error names the first
            /// column whose value is not one of its codes.
            pub fn from_packed(p: &PackedRow) -> Result<Row, ColumnError> {
                Ok(Row { $( $name: {
                    let got = Cell::value({ p.$name });
                    <$ty as Cell>::from_value(got).ok_or(ColumnError::Invalid {
                        column: stringify!($name),
                        expected: <$ty as Cell>::KIND,
                        got,
                    })?
                }, )* })
            }

            /// The row's values in [`COLUMNS`] order.
            pub fn values(&self) -> [Value; COLUMNS.len()] {
                [ $( Cell::value(self.$name), )* ]
            }

            /// Sets column `index` to `value`; the error names the column
            /// when the value has the wrong kind or is not a valid code.
            pub fn set(&mut self, index: usize, value: Value) -> Result<(), ColumnError> {
                let mut i = 0usize;
                $(
                    if i == index {
                        return match <$ty as Cell>::from_value(value) {
                            Some(v) => { self.$name = v; Ok(()) }
                            None => Err(ColumnError::Invalid {
                                column: stringify!($name),
                                expected: <$ty as Cell>::KIND,
                                got: value,
                            }),
                        };
                    }
                    i += 1;
                )*
                let _ = i;
                Err(ColumnError::NoColumn { index })
            }

            /// Sets every column `source` fills to unknown.
            pub fn clear(&mut self, source: ColumnSource) {
                $( if matches!(source, ColumnSource::$source) { self.$name = <$ty as Cell>::UNKNOWN; } )*
            }

            /// Copies every column `source` fills from `other`.
            pub fn copy_columns(&mut self, other: &Row, source: ColumnSource) {
                $( if matches!(source, ColumnSource::$source) { self.$name = other.$name; } )*
            }
        }
    };
    (@count) => { 0 };
    (@count $head:ident $($tail:ident)*) => { 1 + schema!(@count $($tail)*) };
}

use crate::agent::Guard;
use crate::protocol::PhaseKind;

schema! {
    tick: i64 => i64, "1", Time, "tick number, 0 at the first tick of the run";
    t: f64 => f64, "s", Time, "time of the tick, tick * dt_s";
    phase: Option<PhaseKind> => i64, "1", Controller, "phase kind of the tick: an index of meta.phase_names; -1 outside the protocol (the rig's controlled stop)";
    x: f64 => f64, "pos", World, "handle position: the true one (simulation), the drive's last feedback (rig)";
    xdot: f64 => f64, "pos/s", World, "handle velocity: the true one (simulation), the drive's last feedback (rig)";
    x_meas: f64 => f64, "pos", World, "position measurement the controller received this tick";
    xdot_meas: f64 => f64, "pos/s", World, "velocity measurement the controller received this tick";
    fresh: bool => bool, "1", World, "the measurement was new this tick (else the estimators only predicted)";
    tau: f64 => f64, "pos", World, "robot target; NaN outside the protocol";
    tau_h: f64 => f64, "pos", World, "partner target; NaN outside the protocol";
    u: f64 => f64, "trq", Controller, "robot command after its torque guard; on the rig plus the drive's rounding of the torque sent (the robot's part of the torque applied: what its estimators predict with); NaN outside the protocol";
    u_h: f64 => f64, "trq", World, "partner (virtual human) torque; NaN outside the protocol";
    eps: f64 => f64, "trq", World, "motor noise added to the summed torque (simulation; NaN on the rig)";
    torque_nm: f64 => f64, "N m", Rig, "torque sent to the drive after its guard (rig; NaN in simulations)";
    friction_nm: f64 => f64, "N m", Rig, "rig: the handle's friction compensation added to the controller's torque before the guard (rig.friction; 0 when off, NaN during the controlled stop and in simulations)";
    e: f64 => f64, "pos", World, "x - tau";
    e_meas: f64 => f64, "pos", Controller, "the robot's (noisy in integration phases) view of x - tau";
    Lhx_hat: f64 => f64, "trq/pos", Controller, "robot's estimate of the partner gain Lhx (stage 1 or 2)";
    Lhv_hat: f64 => f64, "trq s/pos", Controller, "robot's estimate of the partner gain Lhv (stage 1 or 2)";
    Lhh_hat: f64 => f64, "trq/pos", Controller, "robot's estimate of the partner gain Lhh (stage 1 or 2)";
    Lhx_var: f64 => f64, "(trq/pos)^2", Controller, "posterior variance of Lhx_hat";
    Lhv_var: f64 => f64, "(trq s/pos)^2", Controller, "posterior variance of Lhv_hat";
    Lhh_var: f64 => f64, "(trq/pos)^2", Controller, "posterior variance of Lhh_hat";
    tau_h_hat: f64 => f64, "pos", Controller, "robot's estimate of the partner target (stages 2-3)";
    tau_h_var: f64 => f64, "pos^2", Controller, "posterior variance of x - tau_h_hat";
    e_hat_own: f64 => f64, "pos", Controller, "stage 3: (x - tau)^ from own sensing only";
    e_hat_fused: f64 => f64, "pos", Controller, "stage 3: (x - tau)^ with the partner channel (goal integration)";
    e_hat_own_var: f64 => f64, "pos^2", Controller, "posterior variance of e_hat_own";
    e_hat_fused_var: f64 => f64, "pos^2", Controller, "posterior variance of e_hat_fused";
    partner_var: f64 => f64, "pos^2", Controller, "stage 3: the partner channel's effective variance (inf when not fused)";
    partner_delay_visual_ms: f64 => f64, "ms", Controller, "the partner's visual delay stages 1-2 assume (robot.partner_delay; NaN: the paper's model, or no choice yet)";
    partner_delay_proprioceptive_ms: f64 => f64, "ms", Controller, "the partner's proprioceptive delay stages 1-2 assume (NaN as above, or not identifiable: no velocity term)";
    partner_delay_margin_nats: f64 => f64, "nats", Controller, "robot.partner_delay = \"auto\": profile log-likelihood of the chosen visual delay over the best other one (NaN otherwise)";
    Lx_hat: f64 => f64, "trq/pos", World, "partner's mirrored estimate of the robot gain Lx (simulation section; NaN otherwise)";
    Lv_hat: f64 => f64, "trq s/pos", World, "partner's mirrored estimate of the robot gain Lv";
    Lh_hat: f64 => f64, "trq/pos", World, "partner's mirrored estimate of the robot gain Lh";
    Lx_var: f64 => f64, "(trq/pos)^2", World, "posterior variance of Lx_hat";
    Lv_var: f64 => f64, "(trq s/pos)^2", World, "posterior variance of Lv_hat";
    Lh_var: f64 => f64, "(trq/pos)^2", World, "posterior variance of Lh_hat";
    tau_hat: f64 => f64, "pos", World, "partner's mirrored estimate of the robot target";
    tau_hat_var: f64 => f64, "pos^2", World, "posterior variance of the partner's (x - tau)^";
    e_h_meas: f64 => f64, "pos", World, "goal-integrating partner (simulation section): its (noisy in integration phases) view of x - tau_h; NaN for a virtual human";
    e_h_hat_own: f64 => f64, "pos", World, "goal-integrating partner, stage 3: (x - tau_h)^ from own sensing only";
    e_h_hat_fused: f64 => f64, "pos", World, "goal-integrating partner, stage 3: (x - tau_h)^ with the robot channel";
    wake_latency_us: f64 => f64, "us", Rig, "rig: the tick's start after its deadline, after the spin if rig.realtime.spin_us is set (NaN in simulations)";
    sleep_latency_us: f64 => f64, "us", Rig, "rig: the deadline sleep's return after its own target, the deadline less rig.realtime.spin_us: the OS timer's latency; equal to wake_latency_us without a spin (NaN in simulations)";
    compute_us: f64 => f64, "us", Rig, "rig: wake-up to command sent (NaN in simulations)";
    feedback_age_ticks: i64 => i64, "1", World, "ticks since the last feedback (0 in simulations: a measurement every tick)";
    drive_state: i64 => i64, "1", Rig, "rig: the drive's status, whatever its profile: 0 booting, 1 disabled, 2 enabled, 3 fault (-1 in simulations)";
    guard: Option<Guard> => i64, "1", Rig, "rig: the drive-torque guard 0 passed, 1 clamped, 2 non-finite (-1 controlled stop and simulations)";
    ramp: bool => bool, "1", Rig, "rig: the controlled stop's ticks, braking after a stop request (false in simulations)";
}

impl Row {
    /// The partner identification's columns from an estimate (stages 1-2).
    pub fn set_partner_estimate(&mut self, est: &crate::identifier::PartnerEstimate) {
        [self.Lhx_hat, self.Lhv_hat, self.Lhh_hat] = est.gains;
        [self.Lhx_var, self.Lhv_var, self.Lhh_var] = est.gains_var;
        self.tau_h_hat = est.target;
        self.tau_h_var = est.target_var;
        [
            self.partner_delay_visual_ms,
            self.partner_delay_proprioceptive_ms,
        ] = est.delay_ms;
        self.partner_delay_margin_nats = est.delay_margin_nats;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_bad_codes_name_the_column() {
        let mut row = Row::UNKNOWN;
        for (i, c) in COLUMNS.iter().enumerate() {
            let v = row.values()[i];
            row.set(i, v).expect("its own value");
            assert_eq!(
                c.kind,
                match v {
                    Value::Int(_) => Kind::Int,
                    Value::Float(_) => Kind::Float,
                    Value::Bool(_) => Kind::Bool,
                }
            );
        }
        let phase = COLUMNS.iter().position(|c| c.name == "phase").unwrap();
        for (code, kind) in [
            (0, PhaseKind::Gains),
            (1, PhaseKind::Trajectory),
            (2, PhaseKind::Integration),
        ] {
            row.set(phase, Value::Int(code)).unwrap();
            assert_eq!(row.phase, Some(kind));
        }
        assert!(matches!(
            row.set(phase, Value::Int(3)),
            Err(ColumnError::Invalid {
                column: "phase",
                ..
            })
        ));
        assert!(matches!(
            row.set(COLUMNS.len(), Value::Int(0)),
            Err(ColumnError::NoColumn { .. })
        ));
    }

    /// A packed record holds every column at the offset the Python dtype
    /// gives it (the columns in order, 8 bytes for int64 and float64, 1 for
    /// bool, no padding), each value's native-endian bytes.
    #[test]
    fn packed_row_is_the_dtype_layout() {
        use zerocopy::IntoBytes;
        let mut row = Row::UNKNOWN;
        for (i, c) in COLUMNS.iter().enumerate() {
            let v = match c.kind {
                Kind::Int => Value::Int(-1000 - i as i64),
                Kind::Float => Value::Float(0.5 + i as f64),
                Kind::Bool => Value::Bool(i % 2 == 0),
            };
            // A code column (phase, guard) takes one of its codes.
            if row.set(i, v).is_err() {
                row.set(i, Value::Int(1)).expect("kinds agree");
            }
        }
        let packed = row.packed();
        let bytes = packed.as_bytes();
        let mut at = 0;
        for (c, v) in COLUMNS.iter().zip(row.values()) {
            let width = if c.kind == Kind::Bool { 1 } else { 8 };
            let field = &bytes[at..at + width];
            let (int, float, boolean);
            let expected: &[u8] = match v {
                Value::Int(x) => {
                    int = x.to_ne_bytes();
                    &int
                }
                Value::Float(x) => {
                    float = x.to_ne_bytes();
                    &float
                }
                Value::Bool(x) => {
                    boolean = [u8::from(x)];
                    &boolean
                }
            };
            assert_eq!(field, expected, "column {}", c.name);
            at += width;
        }
        assert_eq!(at, bytes.len(), "no padding, nothing after the last column");
    }

    /// `clear` and `copy_columns` touch exactly the columns of their source.
    #[test]
    fn column_sets_follow_the_source_tags() {
        let mut full = Row::UNKNOWN;
        for (i, c) in COLUMNS.iter().enumerate() {
            let v = match c.kind {
                Kind::Int => Value::Int(0),
                Kind::Float => Value::Float(1.5),
                Kind::Bool => Value::Bool(true),
            };
            full.set(i, v).unwrap();
        }
        for source in [
            ColumnSource::Time,
            ColumnSource::Controller,
            ColumnSource::World,
            ColumnSource::Rig,
        ] {
            let mut cleared = full;
            cleared.clear(source);
            let mut copied = Row::UNKNOWN;
            copied.copy_columns(&full, source);
            for (i, c) in COLUMNS.iter().enumerate() {
                let mine = c.source == source;
                assert_eq!(cleared.values()[i] == full.values()[i], !mine, "{}", c.name);
                assert_eq!(copied.values()[i] == full.values()[i], mine, "{}", c.name);
            }
        }
    }
}
