//! Target trajectories of the paper: what each agent wants the handle to do.
//!
//! A [`Target`] is a sum of up to [`MAX_PARTS`] [`Shape`]s, so "the partner's
//! target plus a chirp" (the Hi5 experiment's robot target) or "0.1 m square
//! wave plus a small sum of cosines" (the simulation section) are values, not
//! code. Evaluating a target never allocates and never panics; every shape is
//! finite for every finite `t` once [`Target::validate`] has passed.

use core::f64::consts::PI;
use libm::{cbrt, cos, floor, sin};

/// How many shapes one [`Target`] can sum.
pub const MAX_PARTS: usize = 3;

/// One elementary trajectory, a function of time `t` in seconds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Shape<'a> {
    /// Always 0.
    #[default]
    Zero,
    /// A constant `value`.
    Constant {
        /// The value.
        value: f64,
    },
    /// `+amplitude` for the first half of each period, `-amplitude` for the
    /// second (starts high at `t = 0`). The simulation's reaching task.
    Square {
        /// Half the peak-to-peak swing.
        amplitude: f64,
        /// Period (s), > 0.
        period_s: f64,
    },
    /// `amplitude * cbrt(sin(2 pi t / period))` with the real cube root: the
    /// Hi5 experiment's rounded square (eqn:human_trajectory, 8 deg, 4 s).
    RoundedSquare {
        /// Peak value.
        amplitude: f64,
        /// Period (s), > 0.
        period_s: f64,
    },
    /// Linear chirp `amplitude * sin(2 pi phase(t))`, `phase = f0 t + (f1 - f0) t^2 / (2 T)`
    /// for `t <= T`; after `T` it continues at `f1`. The Hi5 robot target's
    /// "sweeping chirp signal with frequencies ranging from 0 Hz to 2 Hz".
    Chirp {
        /// Peak value.
        amplitude: f64,
        /// Start frequency (Hz), >= 0.
        f0_hz: f64,
        /// End frequency (Hz), >= 0.
        f1_hz: f64,
        /// Sweep duration `T` (s), > 0.
        duration_s: f64,
    },
    /// `amplitude * sum_{k=1..harmonics} sin(k w t)` (or `cos` when `cosine`):
    /// the simulation's sweeps `[sin t + sin 2t + sin 3t]/1e4`.
    Harmonics {
        /// Weight of every harmonic.
        amplitude: f64,
        /// Base angular frequency `w` (rad/s).
        omega_rad_s: f64,
        /// Number of harmonics, >= 1.
        harmonics: u32,
        /// Use cosines instead of sines.
        cosine: bool,
    },
    /// Samples `samples[i]` at `t = i dt`, linearly interpolated, held
    /// constant before the first and after the last sample.
    Sampled {
        /// The samples; at least one.
        samples: &'a [f64],
        /// Sample period (s), > 0.
        dt_s: f64,
    },
}

/// Why a target is unusable; names the offending field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TargetError {
    /// Index of the part in [`Target::parts`].
    pub part: usize,
    /// The field that is non-finite or out of range.
    pub field: &'static str,
}

impl Shape<'_> {
    /// The value at time `t` (s).
    pub fn at(&self, t: f64) -> f64 {
        match *self {
            Shape::Zero => 0.0,
            Shape::Constant { value } => value,
            Shape::Square {
                amplitude,
                period_s,
            } => {
                let phase = t / period_s - floor(t / period_s);
                if phase < 0.5 {
                    amplitude
                } else {
                    -amplitude
                }
            }
            Shape::RoundedSquare {
                amplitude,
                period_s,
            } => amplitude * cbrt(sin(2.0 * PI * t / period_s)),
            Shape::Chirp {
                amplitude,
                f0_hz,
                f1_hz,
                duration_s,
            } => amplitude * sin(2.0 * PI * chirp_phase(t, f0_hz, f1_hz, duration_s)),
            Shape::Harmonics {
                amplitude,
                omega_rad_s,
                harmonics,
                cosine,
            } => {
                let mut sum = 0.0;
                for k in 1..=harmonics {
                    let arg = f64::from(k) * omega_rad_s * t;
                    sum += if cosine { cos(arg) } else { sin(arg) };
                }
                amplitude * sum
            }
            Shape::Sampled { samples, dt_s } => interpolate(samples, dt_s, t),
        }
    }

    /// Checks every parameter; `Err(field)` names the first bad one.
    pub fn validate(&self) -> Result<(), &'static str> {
        let finite = |v: f64, name| if v.is_finite() { Ok(()) } else { Err(name) };
        let positive = |v: f64, name| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(name)
            }
        };
        match *self {
            Shape::Zero => Ok(()),
            Shape::Constant { value } => finite(value, "value"),
            Shape::Square {
                amplitude,
                period_s,
            }
            | Shape::RoundedSquare {
                amplitude,
                period_s,
            } => {
                finite(amplitude, "amplitude")?;
                positive(period_s, "period_s")
            }
            Shape::Chirp {
                amplitude,
                f0_hz,
                f1_hz,
                duration_s,
            } => {
                finite(amplitude, "amplitude")?;
                if !(f0_hz.is_finite() && f0_hz >= 0.0) {
                    return Err("f0_hz");
                }
                if !(f1_hz.is_finite() && f1_hz >= 0.0) {
                    return Err("f1_hz");
                }
                positive(duration_s, "duration_s")
            }
            Shape::Harmonics {
                amplitude,
                omega_rad_s,
                harmonics,
                ..
            } => {
                finite(amplitude, "amplitude")?;
                finite(omega_rad_s, "omega_rad_s")?;
                if harmonics == 0 {
                    return Err("harmonics");
                }
                Ok(())
            }
            Shape::Sampled { samples, dt_s } => {
                if samples.is_empty() || samples.iter().any(|s| !s.is_finite()) {
                    return Err("samples");
                }
                positive(dt_s, "dt_s")
            }
        }
    }
}

/// Phase (cycles) of a linear chirp: `f0 t + (f1 - f0) t^2 / (2 T)` up to `T`,
/// then continuing at `f1` so the signal stays smooth.
fn chirp_phase(t: f64, f0: f64, f1: f64, duration: f64) -> f64 {
    if t <= duration {
        f0 * t + (f1 - f0) * t * t / (2.0 * duration)
    } else {
        (f0 + f1) * duration / 2.0 + f1 * (t - duration)
    }
}

/// Linear interpolation of `samples` taken every `dt` from `t = 0`, held at
/// the ends.
fn interpolate(samples: &[f64], dt: f64, t: f64) -> f64 {
    let (Some(&first), Some(&last)) = (samples.first(), samples.last()) else {
        return 0.0;
    };
    let pos = t / dt;
    // NaN (from a non-finite t) falls back to the first sample as well.
    if pos.is_nan() || pos <= 0.0 {
        return first;
    }
    let i = floor(pos);
    // `i` is finite and >= 0 here; the cast saturates for huge values.
    let idx = i as usize;
    match (samples.get(idx), samples.get(idx + 1)) {
        (Some(&a), Some(&b)) => a + (b - a) * (pos - i),
        _ => last,
    }
}

/// A target: the sum of up to [`MAX_PARTS`] shapes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Target<'a> {
    /// The summed shapes; unused slots are [`Shape::Zero`].
    pub parts: [Shape<'a>; MAX_PARTS],
}

impl<'a> Target<'a> {
    /// A target made of one shape.
    pub fn single(shape: Shape<'a>) -> Self {
        let mut parts = [Shape::Zero; MAX_PARTS];
        parts[0] = shape;
        Target { parts }
    }

    /// This target plus `shape` in the first free slot; `None` when all
    /// [`MAX_PARTS`] slots are taken.
    pub fn plus(mut self, shape: Shape<'a>) -> Option<Self> {
        let slot = self.parts.iter_mut().find(|p| **p == Shape::Zero)?;
        *slot = shape;
        Some(self)
    }

    /// The value at time `t` (s).
    pub fn at(&self, t: f64) -> f64 {
        self.parts.iter().map(|p| p.at(t)).sum()
    }

    /// Checks every part; the error names the part and the field.
    pub fn validate(&self) -> Result<(), TargetError> {
        for (part, shape) in self.parts.iter().enumerate() {
            shape
                .validate()
                .map_err(|field| TargetError { part, field })?;
        }
        Ok(())
    }
}
