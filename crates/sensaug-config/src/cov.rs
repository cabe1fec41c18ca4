//! Covariance matrices as written in a file: `N` diagonal entries, or an
//! `N x N` nested list. Checked for finiteness, bounds, symmetry and positive
//! definiteness at validation, never in a tick.

use crate::error::ConfigError;
use nalgebra::{SMatrix, SVector};
use schemars::{json_schema, JsonSchema, Schema, SchemaGenerator};
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};
use std::borrow::Cow;
use std::fmt;

/// Largest magnitude of a covariance entry: far above any per-step variance
/// this controller uses, and small enough that sigma-point arithmetic on it
/// stays finite.
pub const MAX_COV_ENTRY: f64 = 1e6;

/// An `N x N` covariance, kept in the form it was written.
#[derive(Clone, Debug, PartialEq)]
pub enum Cov<const N: usize> {
    /// Diagonal entries.
    Diagonal([f64; N]),
    /// The full matrix, row by row.
    Full([[f64; N]; N]),
}

impl<const N: usize> Cov<N> {
    /// A diagonal covariance.
    pub const fn diagonal(d: [f64; N]) -> Self {
        Cov::Diagonal(d)
    }

    /// The matrix, checked: finite entries within [`MAX_COV_ENTRY`],
    /// symmetric, positive definite. `field` names it in errors.
    pub fn matrix(&self, field: &str) -> Result<SMatrix<f64, N, N>, ConfigError> {
        let m = match self {
            Cov::Diagonal(d) => SMatrix::from_diagonal(&SVector::from(*d)),
            Cov::Full(rows) => SMatrix::from_fn(|i, j| rows[i][j]),
        };
        if let Some(v) = m.iter().find(|v| !v.is_finite()) {
            return Err(ConfigError::new(
                field,
                format!("entries must be finite numbers, got {v}; write every entry as a number"),
            ));
        }
        if let Some(v) = m.iter().find(|v| v.abs() > MAX_COV_ENTRY) {
            return Err(ConfigError::new(
                field,
                format!(
                    "entry {} is out of range; keep every entry within +-{}",
                    crate::error::num(*v),
                    crate::error::num(MAX_COV_ENTRY)
                ),
            ));
        }
        if (m - m.transpose()).abs().max() > 1e-12 * m.abs().max() {
            return Err(ConfigError::new(
                field,
                "must be symmetric; make entry (i, j) equal to entry (j, i)",
            ));
        }
        if m.cholesky().is_none() {
            return Err(ConfigError::new(
                field,
                "must be positive definite; raise the diagonal",
            ));
        }
        Ok(m)
    }
}

impl<const N: usize> Serialize for Cov<N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Cov::Diagonal(d) => d.as_slice().serialize(s),
            Cov::Full(rows) => rows
                .iter()
                .map(|r| r.as_slice())
                .collect::<Vec<_>>()
                .serialize(s),
        }
    }
}

/// One list element: a number (diagonal form) or a row (full form).
#[derive(Deserialize)]
#[serde(untagged)]
enum Entry {
    Number(f64),
    Row(Vec<f64>),
}

struct CovVisitor<const N: usize>;

impl<'de, const N: usize> Visitor<'de> for CovVisitor<N> {
    type Value = Cov<N>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "{N} diagonal entries or a {N}x{N} nested list of numbers"
        )
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Cov<N>, A::Error> {
        let mut entries = Vec::with_capacity(N);
        while let Some(e) = seq.next_element::<Entry>().map_err(|_| {
            de::Error::custom(format_args!(
                "every entry must be a number or a list of numbers; expected {N} diagonal \
                 entries or a {N}x{N} nested list"
            ))
        })? {
            entries.push(e);
        }
        let wrong = || {
            de::Error::custom(format_args!(
                "expected {N} diagonal entries or a {N}x{N} nested list, got {} entries",
                entries.len()
            ))
        };
        if entries.len() != N {
            return Err(wrong());
        }
        if entries.iter().all(|e| matches!(e, Entry::Number(_))) {
            let mut d = [0.0; N];
            for (slot, e) in d.iter_mut().zip(&entries) {
                if let Entry::Number(v) = e {
                    *slot = *v;
                }
            }
            return Ok(Cov::Diagonal(d));
        }
        let mut rows = [[0.0; N]; N];
        for (i, e) in entries.iter().enumerate() {
            match e {
                Entry::Row(r) if r.len() == N => rows[i].copy_from_slice(r),
                _ => {
                    return Err(de::Error::custom(format_args!(
                        "row {i} must be a list of {N} numbers; expected {N} diagonal entries \
                         or a {N}x{N} nested list"
                    )))
                }
            }
        }
        Ok(Cov::Full(rows))
    }
}

impl<'de, const N: usize> Deserialize<'de> for Cov<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_seq(CovVisitor::<N>)
    }
}

impl<const N: usize> JsonSchema for Cov<N> {
    fn schema_name() -> Cow<'static, str> {
        format!("Covariance{N}").into()
    }

    fn json_schema(_: &mut SchemaGenerator) -> Schema {
        let number = json_schema!({
            "type": "number",
            "minimum": -MAX_COV_ENTRY,
            "maximum": MAX_COV_ENTRY,
        });
        json_schema!({
            "description": format!(
                "A symmetric positive definite {N}x{N} covariance: {N} diagonal entries \
                 or the full matrix as {N} rows of {N} numbers."
            ),
            "anyOf": [
                {"type": "array", "items": number, "minItems": N, "maxItems": N},
                {
                    "type": "array",
                    "items": {"type": "array", "items": number, "minItems": N, "maxItems": N},
                    "minItems": N,
                    "maxItems": N
                }
            ]
        })
    }
}
