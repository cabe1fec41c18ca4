//! A configuration as TOML, each field preceded by its description from the
//! JSON Schema (which names its unit), so a written preset documents itself.

use crate::schema::ScenarioSpec;
use serde_json::Value;
use toml_edit::{DocumentMut, Item, Table};

fn resolve<'s>(root: &'s Value, schema: &'s Value) -> &'s Value {
    match schema.get("$ref").and_then(Value::as_str) {
        Some(r) => resolve(root, &root["$defs"][r.trim_start_matches("#/$defs/")]),
        None => schema,
    }
}

/// The object schema behind a property (through `$ref` and a nullable `anyOf`).
fn object_schema<'s>(root: &'s Value, schema: &'s Value) -> &'s Value {
    let s = resolve(root, schema);
    match s.get("anyOf").and_then(Value::as_array) {
        Some(bs) => bs
            .iter()
            .map(|b| resolve(root, b))
            .find(|b| b.get("properties").is_some())
            .unwrap_or(s),
        None => s,
    }
}

fn comment(desc: &str) -> String {
    desc.lines()
        .map(|l| format!("# {}\n", l.trim()))
        .collect::<String>()
}

fn annotate(root: &Value, schema: &Value, table: &mut Table) {
    let props = object_schema(root, schema)
        .get("properties")
        .cloned()
        .unwrap_or_default();
    for (key, item) in table.iter_mut() {
        let Some(prop) = props.get(key.get()) else {
            continue;
        };
        let desc = prop
            .get("description")
            .or_else(|| resolve(root, prop).get("description"))
            .and_then(Value::as_str)
            .unwrap_or("");
        match item {
            Item::Table(t) => {
                if !desc.is_empty() {
                    t.decor_mut().set_prefix(format!("\n{}", comment(desc)));
                }
                annotate(root, prop, t);
            }
            Item::ArrayOfTables(a) => {
                let items = prop.get("items").cloned().unwrap_or_default();
                for (i, t) in a.iter_mut().enumerate() {
                    // Describe the fields once, at the first table of the array.
                    if i == 0 {
                        if !desc.is_empty() {
                            t.decor_mut().set_prefix(format!("\n{}", comment(desc)));
                        }
                        annotate(root, &items, t);
                    } else {
                        t.decor_mut().set_prefix("\n");
                    }
                }
            }
            Item::Value(_) => {
                if !desc.is_empty() {
                    let mut k = key;
                    k.leaf_decor_mut().set_prefix(comment(desc));
                }
            }
            Item::None => {}
        }
    }
}

/// The configuration as commented TOML; reads back to the same value.
pub fn to_toml(spec: &ScenarioSpec) -> String {
    let plain = toml::to_string(spec).expect("a validated configuration is TOML");
    let mut doc: DocumentMut = plain.parse().expect("toml writes valid TOML");
    let schema = crate::json_schema();
    doc.decor_mut().set_prefix(
        "# sensaug trial configuration (check it: `sensaug check FILE`;\n\
         # every field, its unit and bounds: `sensaug schema`).\n",
    );
    annotate(schema, schema, doc.as_table_mut());
    doc.to_string()
}
