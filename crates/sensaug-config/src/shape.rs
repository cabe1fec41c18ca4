//! Deserializing a target shape: read `kind`, then the fields of that kind,
//! so that an error names the field inside the shape
//! (`phases[0].robot_target[1].period_s`), which serde's internally tagged
//! enums cannot do.

use crate::error::NESTED;
use crate::schema::{ChirpSpec, ConstantSpec, HarmonicsSpec, SampledSpec, ShapeSpec, SquareSpec};
use serde::de::{self, DeserializeOwned, Deserializer};
use serde::Deserialize;

const KINDS: &str = "constant, square, rounded_square, chirp, harmonics, sampled";

fn fields<T: DeserializeOwned, E: de::Error>(table: toml::Table) -> Result<T, E> {
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(
        |e: serde_path_to_error::Error<toml::de::Error>| {
            let path = e.path().to_string();
            let path = if path == "." { String::new() } else { path };
            E::custom(format_args!(
                "{NESTED}{path}{NESTED}{}",
                e.inner().message()
            ))
        },
    )
}

impl<'de> Deserialize<'de> for ShapeSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let mut table = toml::Table::deserialize(d).map_err(|_| {
            de::Error::custom(format_args!(
                "expected a table with a kind (one of {KINDS}), e.g. {{ kind = \"square\", \
                 amplitude = 1.0, period_s = 2.0 }}"
            ))
        })?;
        let kind = match table.remove("kind") {
            Some(toml::Value::String(k)) => k,
            Some(_) => {
                return Err(de::Error::custom(format_args!(
                    "{NESTED}kind{NESTED}expected a string, one of {KINDS}"
                )))
            }
            None => {
                return Err(de::Error::custom(format_args!(
                    "{NESTED}kind{NESTED}missing; add kind = one of {KINDS}"
                )))
            }
        };
        Ok(match kind.as_str() {
            "constant" => ShapeSpec::Constant(fields::<ConstantSpec, _>(table)?),
            "square" => ShapeSpec::Square(fields::<SquareSpec, _>(table)?),
            "rounded_square" => ShapeSpec::RoundedSquare(fields::<SquareSpec, _>(table)?),
            "chirp" => ShapeSpec::Chirp(fields::<ChirpSpec, _>(table)?),
            "harmonics" => ShapeSpec::Harmonics(fields::<HarmonicsSpec, _>(table)?),
            "sampled" => ShapeSpec::Sampled(fields::<SampledSpec, _>(table)?),
            other => {
                return Err(de::Error::custom(format_args!(
                    "{NESTED}kind{NESTED}unknown shape \"{other}\"; use one of {KINDS}"
                )))
            }
        })
    }
}
