//! `include`: a configuration file may take in the tables of other files
//! (`include = ["calibration.toml"]`, each path relative to the including
//! file's folder), so that a lab keeps one calibration file per handle and
//! every rig configuration includes it.
//!
//! The rule is the rig's: **a setting comes from one file**. A key given in
//! two files is an error naming the key, both files and the fix, never a
//! silent override; tables merge key by key, a list (`phases`) is one value.
//! Included files may include (a cycle, or a file included twice, is an
//! error naming the entry); a missing or unreadable file is an error naming
//! the `include` entry and the path tried. Each file included is recorded
//! in the configuration's `included` list with its SHA-256, so the log's
//! metadata (`meta["config"]["included"]`) says which files a trial ran
//! with. Expanded once, where a file is read ([`crate::parse_file`]); text
//! and tables read without a file refuse `include` ([`crate::Resolved::new`]).

use crate::error::{self, ConfigError};
use crate::schema::{ScenarioSpec, MAX_INCLUDES};
use crate::Format;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The file each setting (a leaf: a value or a list, by its dotted path)
/// was read from, as the user named it.
#[derive(Debug, Default)]
pub(crate) struct Origins(BTreeMap<String, String>);

impl Origins {
    /// The file that set `field` (or the leaf holding it, `phases[2].kind`
    /// in `phases`; or every leaf under it, when they share one file).
    fn of(&self, field: &str) -> Option<&str> {
        let mut f = field;
        loop {
            if let Some(file) = self.0.get(f) {
                return Some(file);
            }
            match f.rfind(['.', '[']) {
                Some(i) => f = &f[..i],
                None => break,
            }
        }
        let mut under = self
            .0
            .range(format!("{field}.")..)
            .take_while(|(k, _)| k.starts_with(&format!("{field}.")))
            .map(|(_, v)| v.as_str());
        let first = under.next()?;
        under.all(|v| v == first).then_some(first)
    }

    /// `e` with the included file that set its field named (an error at a
    /// setting of the top file, or at no setting, is left as it is).
    pub(crate) fn annotate(&self, top: &str, e: ConfigError) -> ConfigError {
        match self.of(&e.field) {
            Some(file) if file != top => {
                let message = format!("{} (set in {file})", e.message);
                ConfigError::new(e.field, message)
            }
            _ => e,
        }
    }
}

/// Whether the text has a top-level `include` (a text that does not parse
/// has none here: its own parse reports the syntax error).
pub(crate) fn names_includes(text: &str, format: Format) -> bool {
    text.contains("include") && table_of(text, format).is_ok_and(|t| t.contains_key("include"))
}

/// The file at `path` (its `text` already read) with every include merged
/// in, parsed, its `included` list recorded; and where each setting came
/// from.
pub(crate) fn expand(path: &Path, text: &str) -> Result<(ScenarioSpec, Origins), ConfigError> {
    let name = path.display().to_string();
    let canonical = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    let mut reader = Reader::default();
    let (mut table, origins) = reader.file(path, canonical, text, &name)?;
    table.insert("included".into(), toml::Value::Array(reader.records));
    let spec =
        crate::spec_of_value(toml::Value::Table(table)).map_err(|e| origins.annotate(&name, e))?;
    Ok((spec, origins))
}

/// Nested reads: the files being read (a cycle), every file read (twice),
/// and the `included` records in reading order.
#[derive(Default)]
struct Reader {
    stack: Vec<PathBuf>,
    seen: BTreeMap<PathBuf, String>,
    records: Vec<toml::Value>,
}

impl Reader {
    /// One file's tables with its includes merged in, and their origins.
    fn file(
        &mut self,
        path: &Path,
        canonical: PathBuf,
        text: &str,
        name: &str,
    ) -> Result<(toml::Table, Origins), ConfigError> {
        let mut table = table_of(text, Format::of_path(path)).map_err(|e| in_file(e, name))?;
        let entries = match table.remove("include") {
            None => Vec::new(),
            Some(toml::Value::Array(a)) if a.iter().all(toml::Value::is_str) => a
                .into_iter()
                .filter_map(|v| v.as_str().map(str::to_string))
                .collect(),
            Some(_) => {
                return Err(ConfigError::new(
                    "include",
                    format!(
                        "in {name}: expected a list of file paths, e.g. include = \
                         [\"calibration.toml\"]; write it as a list of quoted paths"
                    ),
                ))
            }
        };
        // A file written from a configuration that had included others
        // carries their records: kept, in front of this read's.
        if let Some(toml::Value::Array(records)) = table.remove("included") {
            self.records.extend(records);
        }
        let mut origins = Origins::default();
        leaves(&table, "", name, &mut origins);
        self.stack.push(canonical.clone());
        self.seen.insert(canonical, name.to_string());
        let folder = path.parent().unwrap_or(Path::new(""));
        for (i, entry) in entries.iter().enumerate() {
            let field = format!("include[{i}]");
            let tried = folder.join(entry);
            let shown = tried.display();
            let child = tried.canonicalize().map_err(|e| {
                ConfigError::new(
                    &field,
                    format!(
                        "\"{entry}\" in {name}: cannot open {shown}: {}; the path is relative to \
                         the including file's folder: correct it or create the file",
                        crate::io_reason(&e)
                    ),
                )
            })?;
            if self.stack.contains(&child) {
                return Err(ConfigError::new(
                    &field,
                    format!(
                        "\"{entry}\" in {name}: {shown} is already being read (it includes \
                         {name}, directly or through other files): a cycle; remove one of the \
                         includes"
                    ),
                ));
            }
            if let Some(by) = self.seen.get(&child) {
                return Err(ConfigError::new(
                    &field,
                    format!(
                        "\"{entry}\" in {name}: {shown} is included twice (also by {by}); its \
                         settings would be given twice: include it once"
                    ),
                ));
            }
            if self.seen.len() > MAX_INCLUDES {
                return Err(ConfigError::new(
                    &field,
                    format!(
                        "\"{entry}\" in {name}: more than {MAX_INCLUDES} files included; \
                         merge some of them"
                    ),
                ));
            }
            let child_text = crate::read_text(&tried).map_err(|e| {
                ConfigError::new(&field, format!("\"{entry}\" in {name}: {}", e.message))
            })?;
            let child_name = shown.to_string();
            self.records.push(record(&child, &child_text));
            let (child_table, child_origins) =
                self.file(&tried, child, &child_text, &child_name)?;
            merge(&mut table, child_table, "", &origins, &child_origins)?;
            origins.0.extend(child_origins.0);
        }
        self.stack.pop();
        Ok((table, origins))
    }
}

/// The `included` record of a file: its absolute path and SHA-256.
fn record(canonical: &Path, text: &str) -> toml::Value {
    use sha2::Digest;
    let digest = sha2::Sha256::digest(text.as_bytes());
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    let mut t = toml::Table::new();
    t.insert("path".into(), canonical.display().to_string().into());
    t.insert("sha256".into(), hex.into());
    toml::Value::Table(t)
}

/// An error about an included file's text, saying which file.
fn in_file(e: ConfigError, name: &str) -> ConfigError {
    match e.field.as_str() {
        "(config)" => ConfigError::new(name, e.message),
        _ => ConfigError::new(e.field, format!("{} (in {name})", e.message)),
    }
}

/// A file's text as TOML's tables (a JSON file's object read into them);
/// a text that does not parse gets the error the plain parse gives it.
fn table_of(text: &str, format: Format) -> Result<toml::Table, ConfigError> {
    let parsed = match format {
        Format::Toml => text.parse::<toml::Table>().ok(),
        Format::Json => serde_json::from_str::<serde_json::Value>(text)
            .ok()
            .map(without_nulls)
            .and_then(|v| toml::Table::try_from(v).ok()),
    };
    match parsed {
        Some(t) => Ok(t),
        None => Err(crate::parse_str(text, format).err().unwrap_or_else(|| {
            ConfigError::new(
                "(config)",
                "cannot be read as tables; write one table (TOML) or one object (JSON)",
            )
        })),
    }
}

/// JSON's `null` is an absent optional setting (TOML has no null).
fn without_nulls(v: serde_json::Value) -> serde_json::Value {
    match v {
        serde_json::Value::Object(m) => m
            .into_iter()
            .filter(|(_, v)| !v.is_null())
            .map(|(k, v)| (k, without_nulls(v)))
            .collect(),
        serde_json::Value::Array(a) => a.into_iter().map(without_nulls).collect(),
        other => other,
    }
}

/// Records `file` as the origin of every leaf of `table` under `prefix`.
fn leaves(table: &toml::Table, prefix: &str, file: &str, origins: &mut Origins) {
    for (k, v) in table {
        let path = error::join(prefix, k);
        match v {
            toml::Value::Table(t) => leaves(t, &path, file, origins),
            _ => {
                origins.0.insert(path, file.to_string());
            }
        }
    }
}

/// `from` merged into `into`: tables key by key; any other value given in
/// both is a conflict, named with both files.
fn merge(
    into: &mut toml::Table,
    from: toml::Table,
    prefix: &str,
    into_origins: &Origins,
    from_origins: &Origins,
) -> Result<(), ConfigError> {
    for (k, v) in from {
        let path = error::join(prefix, &k);
        match (into.get_mut(&k), v) {
            (None, v) => {
                into.insert(k, v);
            }
            (Some(toml::Value::Table(a)), toml::Value::Table(b)) => {
                merge(a, b, &path, into_origins, from_origins)?
            }
            (Some(_), _) => {
                let first = into_origins.of(&path).unwrap_or("the including file");
                let second = from_origins.of(&path).unwrap_or("the included file");
                return Err(ConfigError::new(
                    &path,
                    format!(
                        "set in both {first} and {second} (included); a setting may come from \
                         one file only, an include never overrides: remove it from one of them"
                    ),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn origins(pairs: &[(&str, &str)]) -> Origins {
        Origins(
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
        )
    }

    #[test]
    fn an_error_names_the_file_its_setting_came_from() {
        let o = origins(&[
            ("phases", "top.toml"),
            ("plant.mass", "cal.toml"),
            ("rig.friction.coulomb_nm", "cal.toml"),
            ("rig.friction.viscous_nm_s_per_rad", "cal.toml"),
            ("rig.can", "top.toml"),
        ]);
        assert_eq!(o.of("phases[2].kind"), Some("top.toml"));
        assert_eq!(o.of("plant.mass"), Some("cal.toml"));
        assert_eq!(o.of("rig.friction"), Some("cal.toml"));
        assert_eq!(o.of("rig"), None, "two files set settings under rig");
        assert_eq!(o.of("world.seed"), None);
        let e = o.annotate("top.toml", ConfigError::new("plant.mass", "too large"));
        assert_eq!(e.message, "too large (set in cal.toml)");
        let e = o.annotate("top.toml", ConfigError::new("phases[0].kind", "bad"));
        assert_eq!(e.message, "bad");
    }

    #[test]
    fn json_nulls_are_absent_settings() {
        let t = table_of(
            r#"{"plant": {"mass": 0.004, "coulomb": null}}"#,
            Format::Json,
        )
        .unwrap();
        assert_eq!(t["plant"].as_table().unwrap().len(), 1);
    }

    #[test]
    fn tables_merge_key_by_key_and_a_value_given_twice_is_refused() {
        let mut a: toml::Table = "[rig]\ncan = \"udp:1\"\n[plant]\ndt_s = 0.001"
            .parse()
            .unwrap();
        let b: toml::Table = "[rig.friction]\ncoulomb_nm = 0.01\n[plant]\nmass = 0.004"
            .parse()
            .unwrap();
        let (oa, ob) = (
            origins(&[("rig.can", "a.toml"), ("plant.dt_s", "a.toml")]),
            origins(&[
                ("rig.friction.coulomb_nm", "b.toml"),
                ("plant.mass", "b.toml"),
            ]),
        );
        merge(&mut a, b, "", &oa, &ob).unwrap();
        assert_eq!(a["plant"]["mass"].as_float(), Some(0.004));
        assert_eq!(a["plant"]["dt_s"].as_float(), Some(0.001));
        assert_eq!(a["rig"]["friction"]["coulomb_nm"].as_float(), Some(0.01));
        let c: toml::Table = "[plant]\nmass = 0.005".parse().unwrap();
        let e = merge(&mut a, c, "", &ob, &origins(&[("plant.mass", "c.toml")])).unwrap_err();
        assert_eq!(e.field, "plant.mass");
        assert!(
            e.message.contains("b.toml") && e.message.contains("c.toml"),
            "{e}"
        );
        assert!(e.message.contains("remove it from one of them"), "{e}");
        // A table in one file, a value in the other.
        let d: toml::Table = "rig = 3".parse().unwrap();
        let e = merge(&mut a, d, "", &oa, &origins(&[("rig", "d.toml")])).unwrap_err();
        assert_eq!(e.field, "rig");
        assert!(e.message.contains("d.toml"), "{e}");
    }
}
