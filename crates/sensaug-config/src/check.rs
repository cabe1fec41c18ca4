//! The bounds of every field are written once, as `#[schemars(...)]`
//! attributes on the schema types; this walker enforces them by reading the
//! generated JSON Schema alongside the parsed configuration, so what editors
//! are told and what is enforced cannot drift apart.
//!
//! It understands the keywords the schema types produce: `$ref`, `anyOf` /
//! `oneOf` (options, shapes, covariances), `properties`, `items`,
//! `minItems`/`maxItems`, `minimum`/`maximum` and their exclusive forms. A
//! non-finite number serializes to JSON `null`; where the schema wants a
//! number, that is reported as non-finite.

use crate::error::{join, num, ConfigError};
use serde_json::Value;

/// Checks `value` (the configuration serialized to JSON) against `schema`.
pub fn bounds(schema: &Value, value: &Value) -> Result<(), ConfigError> {
    walk(schema, schema, value, "")
}

fn resolve<'s>(root: &'s Value, schema: &'s Value) -> &'s Value {
    match schema.get("$ref").and_then(Value::as_str) {
        Some(r) => {
            let name = r.trim_start_matches("#/$defs/");
            let target = &root["$defs"][name];
            resolve(root, target)
        }
        None => schema,
    }
}

fn types(schema: &Value) -> Vec<&str> {
    match schema.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
        _ => Vec::new(),
    }
}

fn json_type(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "boolean",
        Value::Number(_) => "number",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Object(_) => "object",
    }
}

/// Whether `schema` (resolved) could describe `v`, looking one level into
/// arrays and at a `kind` constant, enough to choose among the branches of an
/// `anyOf`/`oneOf`.
fn fits(root: &Value, schema: &Value, v: &Value) -> bool {
    let schema = resolve(root, schema);
    if let Some(branches) = schema.get("anyOf").or_else(|| schema.get("oneOf")) {
        return branches
            .as_array()
            .is_some_and(|bs| bs.iter().any(|b| fits(root, b, v)));
    }
    let ts = types(schema);
    let t = json_type(v);
    let type_ok = ts.is_empty()
        || ts.contains(&t)
        || (t == "number" && ts.contains(&"integer"))
        || (t == "null" && (ts.contains(&"number") || ts.contains(&"integer")));
    if !type_ok {
        return false;
    }
    match v {
        Value::Array(items) => match (items.first(), schema.get("items")) {
            (Some(first), Some(item_schema)) => fits(root, item_schema, first),
            _ => true,
        },
        Value::Object(map) => match (map.get("kind"), schema.pointer("/properties/kind/const")) {
            (Some(k), Some(c)) => k == c,
            _ => true,
        },
        _ => true,
    }
}

fn walk(root: &Value, schema: &Value, v: &Value, path: &str) -> Result<(), ConfigError> {
    let schema = resolve(root, schema);
    if let Some(branches) = schema.get("anyOf").or_else(|| schema.get("oneOf")) {
        let branches = branches.as_array().map(Vec::as_slice).unwrap_or(&[]);
        // The branch that fits; a null that no branch admits as null is a
        // non-finite number and is reported by the numeric branch.
        let chosen = branches
            .iter()
            .find(|b| types(resolve(root, b)).contains(&json_type(v)) && fits(root, b, v))
            .or_else(|| branches.iter().find(|b| fits(root, b, v)));
        return match chosen {
            Some(b) => walk(root, b, v, path),
            None => Ok(()),
        };
    }
    match v {
        Value::Null => {
            let ts = types(schema);
            if !ts.contains(&"null") && (ts.contains(&"number") || ts.contains(&"integer")) {
                return Err(ConfigError::new(
                    path,
                    "must be a finite number (nan and inf are not allowed); write a number",
                ));
            }
            Ok(())
        }
        Value::Number(n) => number(schema, n.as_f64().unwrap_or(f64::NAN), path),
        Value::Array(items) => {
            let n = items.len() as u64;
            let min = schema.get("minItems").and_then(Value::as_u64);
            let max = schema.get("maxItems").and_then(Value::as_u64);
            if min.is_some_and(|m| n < m) || max.is_some_and(|m| n > m) {
                let want = match (min, max) {
                    (Some(a), Some(b)) if a == b => format!("exactly {a}"),
                    (Some(a), Some(b)) => format!("{a} to {b}"),
                    (Some(a), None) => format!("at least {a}"),
                    (None, Some(b)) => format!("at most {b}"),
                    (None, None) => unreachable!("a bound was violated"),
                };
                return Err(ConfigError::new(
                    path,
                    format!("has {n} entries; give {want}"),
                ));
            }
            if let Some(item_schema) = schema.get("items") {
                for (i, item) in items.iter().enumerate() {
                    walk(root, item_schema, item, &format!("{path}[{i}]"))?;
                }
            }
            Ok(())
        }
        Value::Object(map) => {
            if let Some(Value::Object(props)) = schema.get("properties") {
                for (name, sub) in props {
                    if let Some(child) = map.get(name) {
                        walk(root, sub, child, &join(path, name))?;
                    }
                }
            }
            Ok(())
        }
        Value::Bool(_) | Value::String(_) => Ok(()),
    }
}

fn number(schema: &Value, x: f64, path: &str) -> Result<(), ConfigError> {
    let get = |k: &str| schema.get(k).and_then(Value::as_f64);
    let (min, xmin, max, xmax) = (
        get("minimum"),
        get("exclusiveMinimum"),
        get("maximum"),
        get("exclusiveMaximum"),
    );
    let ok = min.is_none_or(|m| x >= m)
        && xmin.is_none_or(|m| x > m)
        && max.is_none_or(|m| x <= m)
        && xmax.is_none_or(|m| x < m);
    if ok {
        return Ok(());
    }
    let low = min
        .map(|m| format!(">= {}", num(m)))
        .or(xmin.map(|m| format!("> {}", num(m))));
    let high = max
        .map(|m| format!("<= {}", num(m)))
        .or(xmax.map(|m| format!("< {}", num(m))));
    let range = match (low, high) {
        (Some(l), Some(h)) => format!("{l} and {h}"),
        (Some(l), None) => l,
        (None, Some(h)) => h,
        (None, None) => unreachable!("a bound was violated"),
    };
    Err(ConfigError::new(
        path,
        format!("{} is out of range; it must be {range}", num(x)),
    ))
}
