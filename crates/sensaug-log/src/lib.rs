//! The one log schema of sensaug, shared by simulated trials and rig runs.
//!
//! * [`COLUMNS`]: every column once — name, unit, kind (integer, float,
//!   boolean), who fills it and a one-line description — and [`Row`], one
//!   tick of a log with one field per column (both generated from the same
//!   table, `sensaug_core::row`, re-exported here: the simulation and the
//!   rig loop fill the same `no_std` row). Columns one side cannot know are
//!   NaN (floats) or [`UNKNOWN`] (integers).
//! * The file format ([`write_header`], [`format_row`], [`write_footer`]):
//!   CSV text; `#` lines carry the metadata (a format line, then one JSON
//!   line: configuration, versions, units, phase names, start time, loop
//!   settings) and, after the last row, the run's end status. Floats are
//!   written in their shortest round-trip form, so reloading is bit-exact.
//!   Every row, the metadata line and the end line carry a chained CRC-32
//!   ([`Checksum`]), so a changed, lost or reordered line is detected; the
//!   metadata records the configuration's SHA-256 ([`config_sha256`]).
//!   Why this format: `docs/logs.md`.
//! * [`read`]: the file back, every checksum verified (the Python loader,
//!   `sensaug.load_log`, is an independent implementation of the same rules).

#![deny(missing_docs)]
#![allow(non_snake_case)]

use sensaug_core::protocol::PhaseKind;
pub use sensaug_core::row::{
    Cell, Column, ColumnError, ColumnSource, Kind, PackedRow, Row, Value, COLUMNS, UNITS, UNKNOWN,
};
use std::io::{self, Write};
use std::path::Path;
use std::process::Command;

/// The first line of every log file: format name and version.
pub const FORMAT_LINE: &str = "# sensaug-log 2";
/// Version of the schema and the file layout (bumped on any change to either).
/// 2: the chained CRC-32 on every row and `#` JSON line, `config_sha256`.
pub const FORMAT_VERSION: u32 = 2;
/// The header name of every data row's last field, after the schema's
/// columns: the row's checksum ([`Checksum`]), an unsigned decimal integer.
pub const CHECKSUM_FIELD: &str = "crc32";
/// How a `#` JSON line (the metadata, the end status) ends: this key, its
/// checksum in decimal, and the object's closing brace.
pub const JSON_CHECKSUM_KEY: &str = ",\"crc32\":";

/// CRC-32/ISO-HDLC: the CRC of zlib, gzip, PNG and Ethernet
/// (`zlib.crc32` in Python); slice-by-16 tables (16 KiB) for speed.
static CRC32: crc::Crc<u32, crc::Table<16>> =
    crc::Crc::<u32, crc::Table<16>>::new(&crc::CRC_32_ISO_HDLC);

/// The running checksum of a log file: the CRC-32 ([`CRC32`]) of every
/// checksummed byte so far. The checksummed bytes of a line are all its
/// bytes before its checksum: for a data row, up to (not including) the
/// comma before the last field; for a `#` JSON line, up to (not including)
/// [`JSON_CHECKSUM_KEY`]. The metadata line is the first, then each row,
/// then the end line; each carries the running value after its own bytes.
/// A changed line fails at itself; a deleted, duplicated or reordered one at
/// the next line. A line's value is `zlib.crc32(its bytes, previous value)`.
#[derive(Clone)]
pub struct Checksum(crc::Digest<'static, u32, crc::Table<16>>);

impl Default for Checksum {
    fn default() -> Self {
        Checksum(CRC32.digest())
    }
}

impl Checksum {
    /// Nothing checksummed yet (the value before the metadata line: 0).
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one line's checksummed bytes; the running CRC-32 after them.
    pub fn add(&mut self, bytes: &[u8]) -> u32 {
        self.0.update(bytes);
        self.0.clone().finalize()
    }
}
/// Names of the phase codes in the `phase` column (index = code).
pub const PHASE_NAMES: [&str; 3] = PhaseKind::NAMES;

/// Bytes this process can still take: `MemAvailable` of `/proc/meminfo`,
/// and under a cgroup (v2) memory limit what is left of it; `None` where
/// neither can be read (not Linux).
pub fn available_bytes() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let available = meminfo.as_deref().and_then(|text| {
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib.saturating_mul(1024))
    });
    let cgroup = std::fs::read_to_string("/proc/self/cgroup")
        .ok()
        .and_then(|text| {
            let path = text.lines().find_map(|l| l.strip_prefix("0::"))?.to_owned();
            let dir = Path::new("/sys/fs/cgroup").join(path.trim_start_matches('/'));
            let read = |f: &str| std::fs::read_to_string(dir.join(f)).ok();
            let max: u64 = read("memory.max")?.trim().parse().ok()?; // "max": no limit
            let current: u64 = read("memory.current")?.trim().parse().ok()?;
            Some(max.saturating_sub(current))
        });
    match (available, cgroup) {
        (Some(a), Some(c)) => Some(a.min(c)),
        (a, c) => a.or(c),
    }
}

/// The header row: the column names, then [`CHECKSUM_FIELD`], separated by
/// commas.
pub fn header_row() -> String {
    let mut names: Vec<&str> = COLUMNS.iter().map(|c| c.name).collect();
    names.push(CHECKSUM_FIELD);
    names.join(",")
}

/// Appends `v` in its shortest form that reads back to the same bits:
/// plain decimal for moderate magnitudes (always with a `.` or an exponent,
/// so readers infer a float), exponent form otherwise; `nan`, `inf`, `-inf`.
pub fn format_float(v: f64, out: &mut Vec<u8>) {
    // Writing to a Vec cannot fail.
    let _ = if v.is_nan() {
        out.write_all(b"nan")
    } else if v.is_infinite() {
        out.write_all(if v > 0.0 { b"inf" } else { b"-inf" })
    } else if v == 0.0 || (1e-5..1e16).contains(&v.abs()) {
        // Rust's Display prints the shortest digits that round-trip.
        let start = out.len();
        let r = write!(out, "{v}");
        if !out[start..].contains(&b'.') {
            out.extend_from_slice(b".0");
        }
        r
    } else {
        write!(out, "{v:e}")
    };
}

/// Appends one CSV line (with its newline) for `row`: its values, then its
/// checksum (`sum` advanced over the values' bytes).
pub fn format_row(row: &Row, sum: &mut Checksum, out: &mut Vec<u8>) {
    let start = out.len();
    for (i, v) in row.values().iter().enumerate() {
        if i > 0 {
            out.push(b',');
        }
        // Writing to a Vec cannot fail.
        let _ = match *v {
            Value::Int(n) => write!(out, "{n}"),
            Value::Float(f) => {
                format_float(f, out);
                Ok(())
            }
            Value::Bool(b) => out.write_all(if b { b"1" } else { b"0" }),
        };
    }
    let crc = sum.add(&out[start..]);
    let _ = writeln!(out, ",{crc}");
}

/// Checks a data line's checksum (the line without its newline) against the
/// running one, which it advances; the line's values without the checksum.
pub fn check_row<'a>(line: &'a str, sum: &mut Checksum) -> Result<&'a str, String> {
    let (values, crc) = line
        .rsplit_once(',')
        .ok_or_else(|| format!("no {CHECKSUM_FIELD} field"))?;
    check_crc(values, crc, sum)?;
    Ok(values)
}

/// Checks a `#` JSON line's checksum (the line without its newline) against
/// the running one, which it advances; the line's JSON without the checksum.
pub fn check_json_line(line: &str, sum: &mut Checksum) -> Result<serde_json::Value, String> {
    let at = line
        .rfind(JSON_CHECKSUM_KEY)
        .ok_or_else(|| format!("no {JSON_CHECKSUM_KEY:?} at its end"))?;
    let crc = line[at + JSON_CHECKSUM_KEY.len()..]
        .strip_suffix('}')
        .ok_or("does not end with its checksum and '}'")?;
    check_crc(&line[..at], crc, sum)?;
    let json = line[..at]
        .strip_prefix("# ")
        .ok_or("does not start with \"# \"")?;
    serde_json::from_str(&format!("{json}}}")).map_err(|e| format!("not JSON: {e}"))
}

fn check_crc(checked: &str, crc: &str, sum: &mut Checksum) -> Result<(), String> {
    let computed = sum.add(checked.as_bytes());
    let written: u32 = crc
        .parse()
        .map_err(|_| format!("checksum {crc:?} is not a 32-bit decimal number"))?;
    if written != computed {
        return Err(format!(
            "checksum {written} but the bytes give {computed}: this line, or the one before it, \
             changed after it was written"
        ));
    }
    Ok(())
}

/// Reads the values of one data row (the line without its newline and
/// without its checksum, [`check_row`]); `Err` names the first bad column.
pub fn parse_values(values: &str) -> Result<Row, String> {
    let mut row = Row::UNKNOWN;
    let mut n = 0;
    for (i, field) in values.split(',').enumerate() {
        let col = COLUMNS
            .get(i)
            .ok_or_else(|| format!("more than {} fields", COLUMNS.len()))?;
        let bad = |e: &dyn std::fmt::Display| format!("{}: {e} ({field:?})", col.name);
        let value = match col.kind {
            Kind::Int => Value::Int(field.parse().map_err(|e| bad(&e))?),
            Kind::Float => Value::Float(field.parse().map_err(|e| bad(&e))?),
            Kind::Bool => match field {
                "0" => Value::Bool(false),
                "1" => Value::Bool(true),
                _ => return Err(bad(&"expected 0 or 1")),
            },
        };
        row.set(i, value).map_err(|e| e.to_string())?;
        n = i + 1;
    }
    if n != COLUMNS.len() {
        return Err(format!("{n} fields, expected {}", COLUMNS.len()));
    }
    Ok(row)
}

/// Reads one data line written by [`format_row`] (without its newline),
/// checking its checksum first.
pub fn parse_row(line: &str, sum: &mut Checksum) -> Result<Row, String> {
    parse_values(check_row(line, sum)?)
}

/// A log file read back by [`read`].
#[derive(Clone, Debug, PartialEq)]
pub struct LogText {
    /// The metadata (without its checksum).
    pub meta: serde_json::Value,
    /// One row per data line.
    pub rows: Vec<Row>,
    /// The end status (`meta["end"]` in Python), `None` without an end line.
    pub end: Option<serde_json::Value>,
}

/// Reads a whole log file of this version, verifying every checksum; a
/// partial last line (no newline: a killed writer) is ignored. `Err` is
/// `line N: what`.
pub fn read(text: &str) -> Result<LogText, String> {
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    let mut lines = complete.lines().enumerate().map(|(i, l)| (i + 1, l));
    let at = |n: usize| move |e: String| format!("line {n}: {e}");
    match lines.next() {
        Some((_, FORMAT_LINE)) => {}
        _ => return Err(format!("line 1: not {FORMAT_LINE:?}")),
    }
    let mut sum = Checksum::new();
    let (n, line) = lines.next().ok_or("line 2: no metadata line")?;
    let meta = check_json_line(line, &mut sum).map_err(at(n))?;
    match lines.next() {
        Some((_, h)) if h == header_row() => {}
        _ => return Err("line 3: not the header row of this schema".into()),
    }
    let (mut rows, mut end) = (Vec::new(), None);
    for (n, line) in lines {
        if end.is_some() {
            return Err(format!("line {n}: after the end-status line"));
        }
        if line.starts_with('#') {
            let mut json = check_json_line(line, &mut sum).map_err(at(n))?;
            end = Some(json["end"].take());
        } else {
            rows.push(parse_row(line, &mut sum).map_err(at(n))?);
        }
    }
    Ok(LogText { meta, rows, end })
}

/// Where a log comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// A simulated trial (`sensaug.experiment.run`).
    Simulation,
    /// A run of the real-time loop (`sensaug-rt`).
    Rig,
}

impl Source {
    /// `"simulation"` or `"rig"`.
    pub fn name(self) -> &'static str {
        match self {
            Source::Simulation => "simulation",
            Source::Rig => "rig",
        }
    }
}

/// What the writer of a log knows about its run, besides the schema.
#[derive(Clone, Debug, PartialEq)]
pub struct RunInfo {
    /// Simulation or rig.
    pub source: Source,
    /// The configuration as written by the user (TOML as JSON), from which
    /// `sensaug.ScenarioConfig.from_dict` rebuilds the trial.
    pub config: serde_json::Value,
    /// Every setting resolved (defaults filled, gains computed).
    pub resolved: serde_json::Value,
    /// `git rev-parse HEAD` of the source tree, `-dirty` if modified; `None`
    /// when unknown.
    pub git_commit: Option<String>,
    /// Start of the run (s since the Unix epoch, UTC).
    pub start_unix_s: f64,
    /// The loop's settings (rig runs), else `Null`.
    pub loop_settings: serde_json::Value,
}

/// The metadata line's JSON: format, versions, source, start time, the
/// configuration, every column with its unit and kind, the phase names and
/// the unit symbols.
pub fn metadata(info: &RunInfo) -> serde_json::Value {
    let columns: Vec<serde_json::Value> = COLUMNS
        .iter()
        .map(|c| {
            serde_json::json!({
                "name": c.name, "unit": c.unit, "kind": c.kind.name(), "description": c.description,
            })
        })
        .collect();
    let units: serde_json::Map<String, serde_json::Value> = UNITS
        .iter()
        .map(|(k, v)| (k.to_string(), serde_json::Value::from(*v)))
        .collect();
    serde_json::json!({
        "format": "sensaug-log",
        "format_version": FORMAT_VERSION,
        "source": info.source.name(),
        "config_sha256": config_sha256(&info.config),
        "package_version": env!("CARGO_PKG_VERSION"),
        "git_commit": info.git_commit,
        "start_time_utc": iso8601_utc(info.start_unix_s),
        "start_unix_s": info.start_unix_s,
        "config": info.config,
        "resolved": info.resolved,
        "loop": info.loop_settings,
        "columns": columns,
        "phase_names": PHASE_NAMES,
        "unknown_int": UNKNOWN,
        "units": units,
    })
}

/// The schema as one JSON value, for readers in other languages
/// (`sensaug.logs`): the format line and version, the checksum keys,
/// `columns` as `[name, unit, kind, description]`, `sources` (who fills
/// each column: time, controller, world, rig), the phase names, the
/// unknown-integer sentinel and the unit symbols.
pub fn schema() -> serde_json::Value {
    let columns: Vec<[&str; 4]> = COLUMNS
        .iter()
        .map(|c| [c.name, c.unit, c.kind.name(), c.description])
        .collect();
    let sources: serde_json::Map<String, serde_json::Value> = COLUMNS
        .iter()
        .map(|c| (c.name.to_string(), c.source.name().into()))
        .collect();
    serde_json::json!({
        "format_line": FORMAT_LINE,
        "format_version": FORMAT_VERSION,
        "checksum_field": CHECKSUM_FIELD,
        "json_checksum_key": JSON_CHECKSUM_KEY,
        "columns": columns,
        "sources": sources,
        "phase_names": PHASE_NAMES,
        "unknown_int": UNKNOWN,
        "units": UNITS,
    })
}

/// Why bytes are not packed records ([`rows_from_records`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RecordsError {
    /// Not a whole number of records.
    Length(usize),
    /// Record `row` has a bool byte other than 0 or 1.
    NotBool(usize),
    /// Record `row` holds a value its column does not take.
    Column(usize, ColumnError),
}

impl std::fmt::Display for RecordsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let size = RECORD_BYTES;
        match self {
            RecordsError::Length(n) => write!(
                f,
                "records: {n} bytes is not a whole number of {size}-byte records; \
                 pass a structured array of sensaug.logs.DTYPE"
            ),
            RecordsError::NotBool(k) => write!(f, "records[{k}]: a bool column is not 0 or 1"),
            RecordsError::Column(k, e) => write!(f, "data.{e} (row {k})"),
        }
    }
}

/// Rows from the bytes of packed records ([`PackedRow`], the layout of
/// `sensaug.logs.DTYPE`); the error names the record and the column.
pub fn rows_from_records(bytes: &[u8]) -> Result<Vec<Row>, RecordsError> {
    use zerocopy::TryFromBytes;
    let size = RECORD_BYTES;
    if bytes.len() % size != 0 {
        return Err(RecordsError::Length(bytes.len()));
    }
    let row = |(k, chunk)| {
        let packed = PackedRow::try_read_from_bytes(chunk).map_err(|_| RecordsError::NotBool(k))?;
        Row::from_packed(&packed).map_err(|e| RecordsError::Column(k, e))
    };
    bytes.chunks_exact(size).enumerate().map(row).collect()
}

/// Bytes of one packed record ([`PackedRow`]: the columns in schema order,
/// native-endian int64 / float64, bool as one byte; `sensaug.logs.DTYPE`).
pub const RECORD_BYTES: usize = std::mem::size_of::<PackedRow>();

/// Appends `row` to `out` as one packed record (the inverse of
/// [`rows_from_records`]).
pub fn push_record(row: &Row, out: &mut Vec<u8>) {
    use zerocopy::IntoBytes;
    out.extend_from_slice(row.packed().as_bytes());
}

/// Rows as the bytes of packed records (every path of log rows to numpy
/// returns these; `sensaug.logs.from_records` views them).
pub fn records_from_rows(rows: &[Row]) -> Vec<u8> {
    let mut out = Vec::with_capacity(rows.len() * RECORD_BYTES);
    rows.iter().for_each(|r| push_record(r, &mut out));
    out
}

/// Writes a whole log: the header ([`write_header`]), one line per row,
/// then the end-status line unless `end` is `Null`.
pub fn write_log(
    out: &mut impl Write,
    meta: &serde_json::Value,
    rows: &[Row],
    end: &serde_json::Value,
) -> io::Result<()> {
    let mut sum = write_header(out, meta)?;
    let mut line = Vec::with_capacity(1024);
    for r in rows {
        line.clear();
        format_row(r, &mut sum, &mut line);
        out.write_all(&line)?;
    }
    if !end.is_null() {
        write_footer(out, end, &mut sum)?;
    }
    out.flush()
}

/// Writes the format line, the metadata line (`meta` stamped with this
/// format and version, and its checksum) and the header row; the running
/// checksum to write the rows with.
pub fn write_header(out: &mut impl Write, meta: &serde_json::Value) -> io::Result<Checksum> {
    let mut meta = meta.clone();
    let Some(fields) = meta.as_object_mut() else {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "the log metadata must be a JSON object",
        ));
    };
    fields.remove("crc32");
    fields.insert("format".into(), "sensaug-log".into());
    fields.insert("format_version".into(), FORMAT_VERSION.into());
    let mut sum = Checksum::new();
    let line = json_line(&meta, &mut sum);
    write!(out, "{FORMAT_LINE}\n{line}{}\n", header_row())?;
    Ok(sum)
}

/// Writes the end-status line after the last row: `# {"end": ...,"crc32":N}`.
pub fn write_footer(
    out: &mut impl Write,
    end: &serde_json::Value,
    sum: &mut Checksum,
) -> io::Result<()> {
    out.write_all(json_line(&serde_json::json!({ "end": end }), sum).as_bytes())
}

/// A `#` JSON line of a non-empty object with its checksum, newline ended.
fn json_line(object: &serde_json::Value, sum: &mut Checksum) -> String {
    // serde_json never writes a raw newline inside a string, so the line is
    // one line; a non-empty object ends with '}', replaced by the checksum.
    let text = object.to_string();
    let checked = format!("# {}", &text[..text.len() - 1]);
    let crc = sum.add(checked.as_bytes());
    format!("{checked}{JSON_CHECKSUM_KEY}{crc}}}\n")
}

/// SHA-256 (64 lowercase hex digits) of a configuration's canonical JSON
/// text: compact, every object's keys sorted (by their UTF-8 bytes), numbers
/// as serde_json writes them (shortest round-trip form). The metadata's
/// `config_sha256`; `sensaug.replay` recomputes it from `meta["config"]`
/// (`sensaug._core.config_sha256`) to tell an edited configuration.
pub fn config_sha256(config: &serde_json::Value) -> String {
    use sha2::Digest;
    let digest = sha2::Sha256::digest(canonical(config).to_string().as_bytes());
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// `v` with every object's keys in sorted order (whether or not serde_json
/// keeps insertion order).
fn canonical(v: &serde_json::Value) -> serde_json::Value {
    match v {
        serde_json::Value::Object(map) => {
            let mut keys: Vec<&String> = map.keys().collect();
            keys.sort();
            serde_json::Value::Object(
                keys.into_iter()
                    .map(|k| (k.clone(), canonical(&map[k])))
                    .collect(),
            )
        }
        serde_json::Value::Array(items) => {
            serde_json::Value::Array(items.iter().map(canonical).collect())
        }
        other => other.clone(),
    }
}

/// Seconds since the Unix epoch, now.
pub fn now_unix_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(f64::NAN, |d| d.as_secs_f64())
}

/// `s` seconds after the Unix epoch as `YYYY-MM-DDTHH:MM:SS.mmmZ`.
pub fn iso8601_utc(s: f64) -> String {
    if !s.is_finite() {
        return "unknown".into();
    }
    let ms = (s * 1e3).floor() as i64;
    let (days, ms_of_day) = (ms.div_euclid(86_400_000), ms.rem_euclid(86_400_000));
    let (y, m, d) = civil_from_days(days);
    let (h, rest) = (ms_of_day / 3_600_000, ms_of_day % 3_600_000);
    let (min, rest) = (rest / 60_000, rest % 60_000);
    format!(
        "{y:04}-{m:02}-{d:02}T{h:02}:{min:02}:{:02}.{:03}Z",
        rest / 1000,
        rest % 1000
    )
}

/// Days since 1970-01-01 to the proleptic Gregorian `(year, month, day)`
/// (H. Hinnant's "civil_from_days": 400-year eras of 146097 days, years
/// starting in March so the leap day is last).
fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// The git commit of the checkout containing `dir` (`-dirty` when tracked
/// files differ from it); `None` when git or the checkout is missing.
/// Set-up only: runs `git` twice.
pub fn git_commit(dir: &Path) -> Option<String> {
    let git = |args: &[&str]| {
        Command::new("git")
            .arg("-C")
            .arg(dir)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let head = git(&["rev-parse", "HEAD"]).filter(|h| !h.is_empty())?;
    let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).map(|s| !s.is_empty());
    Some(match dirty {
        Some(true) => format!("{head}-dirty"),
        _ => head,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Packed records read back as the rows they were packed from, to the
    /// bit; a record holding no valid code, or a partial record, is refused.
    #[test]
    fn packed_records_read_back_as_rows() {
        use zerocopy::IntoBytes;
        let mut rows = [Row::UNKNOWN; 2];
        (rows[1].tick, rows[1].x, rows[1].fresh) = (1, -0.25, true);
        let bytes = records_from_rows(&rows);
        assert_eq!(bytes.len(), 2 * RECORD_BYTES);
        assert_eq!(&bytes[RECORD_BYTES..], rows[1].packed().as_bytes());
        let back = rows_from_records(&bytes).unwrap();
        assert_eq!(records_from_rows(&back), bytes);
        let mut bad = rows[0].packed();
        bad.phase = 99;
        assert!(matches!(
            rows_from_records(bad.as_bytes()),
            Err(RecordsError::Column(0, _))
        ));
        assert_eq!(
            rows_from_records(&bytes[1..]),
            Err(RecordsError::Length(bytes.len() - 1))
        );
    }

    /// The metadata travels as JSON (Python's `json` <-> serde_json): every
    /// float must come back with the same bits, which serde_json's parser
    /// guarantees only with its `float_roundtrip` feature (without it, 29,585
    /// of these ~100,000 random finite values came back one ulp off).
    #[test]
    fn metadata_floats_survive_json_to_the_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut off = 0;
        for _ in 0..100_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let value = f64::from_bits(state);
            if !value.is_finite() {
                continue;
            }
            let text = serde_json::to_string(&value).unwrap();
            let back: f64 = serde_json::from_str(&text).unwrap();
            off += usize::from(back.to_bits() != value.to_bits());
        }
        assert_eq!(off, 0, "{off} floats changed through JSON");
    }

    #[test]
    fn names_are_unique_and_the_header_matches() {
        let mut names: Vec<_> = COLUMNS.iter().map(|c| c.name).collect();
        names.push(CHECKSUM_FIELD);
        assert_eq!(header_row().split(',').collect::<Vec<_>>(), names);
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), COLUMNS.len() + 1);
    }

    #[test]
    fn every_unit_is_defined() {
        for c in COLUMNS {
            let base = c.unit.strip_suffix("^2").unwrap_or(c.unit);
            let base = base.trim_start_matches('(').trim_end_matches(')');
            let ok = UNITS.iter().any(|(u, _)| *u == base);
            assert!(ok, "{}: unit {:?} not in UNITS", c.name, c.unit);
        }
    }

    #[test]
    fn phase_codes_index_the_names() {
        for (kind, name) in [
            (PhaseKind::Gains, "gains"),
            (PhaseKind::Trajectory, "trajectory"),
            (PhaseKind::Integration, "integration"),
        ] {
            assert_eq!(PHASE_NAMES[kind.code() as usize], name);
        }
    }

    #[test]
    fn floats_round_trip_bit_exactly() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            0.1,
            1.0 / 3.0,
            1e-5,
            9.999_999_999_999_999e-6,
            1e16,
            123_456_789.123_456_79,
            f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            -f64::MAX,
            f64::EPSILON,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for v in values {
            let mut s = Vec::new();
            format_float(v, &mut s);
            let text = String::from_utf8(s).unwrap();
            assert!(text.len() <= 24, "{text}");
            let back: f64 = text.parse().unwrap();
            assert_eq!(back.to_bits(), v.to_bits(), "{v:e} -> {text}");
            assert!(
                text.contains(['.', 'e', 'n']),
                "{text}: readers would infer an integer"
            );
        }
        let mut s = Vec::new();
        format_float(f64::NAN, &mut s);
        assert_eq!(s, b"nan");
    }

    #[test]
    fn a_simulated_tick_round_trips_through_a_line() {
        let row = Row {
            tick: 123,
            t: 0.123,
            phase: Some(PhaseKind::Integration),
            x: 1.0 / 7.0,
            xdot: -3.25e-7,
            x_meas: 1.0 / 7.0 + 1e-4,
            xdot_meas: -3.25e-7 - 2e-4,
            fresh: true,
            tau: 8.0,
            tau_h: -8.0,
            u: 0.5,
            u_h: 0.3,
            eps: 1e-20,
            e: 1.0 / 7.0 - 8.0,
            e_meas: 0.25,
            Lhx_hat: 0.1,
            Lhx_var: 1e-3,
            feedback_age_ticks: 0,
            ..Row::UNKNOWN
        };
        let mut line = Vec::new();
        format_row(&row, &mut Checksum::new(), &mut line);
        assert_eq!(line.last(), Some(&b'\n'));
        let text = std::str::from_utf8(&line[..line.len() - 1]).unwrap();
        let back = parse_row(text, &mut Checksum::new()).unwrap();
        assert_eq!((back.phase, back.guard), (row.phase, None));
        for (a, b) in back.values().iter().zip(row.values()) {
            match (*a, b) {
                (Value::Float(a), Value::Float(b)) => {
                    assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()))
                }
                (a, b) => assert_eq!(a, b),
            }
        }
    }

    #[test]
    fn outside_the_protocol_the_phase_is_unknown() {
        assert_eq!(Row::UNKNOWN.values()[2], Value::Int(UNKNOWN));
        let phase = Row::UNKNOWN.packed().phase;
        assert_eq!(phase, UNKNOWN);
    }

    #[test]
    fn bad_lines_name_the_column() {
        let mut line = Vec::new();
        format_row(&Row::UNKNOWN, &mut Checksum::new(), &mut line);
        let text = String::from_utf8(line).unwrap();
        let values = check_row(text.trim_end(), &mut Checksum::new()).unwrap();
        assert!(parse_values(values).is_ok());
        let bad = values.replacen("-1", "x", 1);
        assert!(parse_values(&bad).unwrap_err().starts_with("tick:"));
        let short = &values[..values.rfind(',').unwrap()];
        assert!(parse_values(short).unwrap_err().contains("fields"));
        let mut row = Row::UNKNOWN;
        assert!(row
            .set(1, Value::Int(3))
            .unwrap_err()
            .to_string()
            .starts_with("t: expected float"));
    }

    /// The checksum is CRC-32/ISO-HDLC (its catalogue check value), and a
    /// line's value is the CRC of every checksummed byte so far: what
    /// `zlib.crc32(line, previous)` computes.
    #[test]
    fn the_checksum_is_the_running_crc32() {
        assert_eq!(Checksum::new().add(b"123456789"), 0xCBF4_3926);
        let mut sum = Checksum::new();
        sum.add(b"1234");
        assert_eq!(sum.add(b"56789"), 0xCBF4_3926);
        assert_eq!(Checksum::new().add(b""), 0);
    }

    fn small_log(rows: usize, end: bool) -> String {
        let info = RunInfo {
            source: Source::Simulation,
            config: serde_json::json!({"b": 1, "a": [0.5, 1e-5]}),
            resolved: serde_json::Value::Null,
            git_commit: None,
            start_unix_s: 0.0,
            loop_settings: serde_json::Value::Null,
        };
        let mut out = Vec::new();
        let mut sum = write_header(&mut out, &metadata(&info)).unwrap();
        for k in 0..rows {
            let row = Row {
                tick: k as i64,
                fresh: k % 2 == 0,
                x: k as f64 / 3.0,
                ..Row::UNKNOWN
            };
            format_row(&row, &mut sum, &mut out);
        }
        if end {
            write_footer(&mut out, &serde_json::json!({"ticks": rows}), &mut sum).unwrap();
        }
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn a_written_log_reads_back_verified() {
        let text = small_log(5, true);
        let log = read(&text).unwrap();
        assert_eq!(log.rows.len(), 5);
        assert_eq!(log.rows[3].x, 1.0);
        assert!(!log.rows[3].fresh);
        assert_eq!(log.end, Some(serde_json::json!({"ticks": 5})));
        assert_eq!(log.meta["format_version"], FORMAT_VERSION);
        assert!(log.meta.get("crc32").is_none());
        // A killed writer: the partial last line is ignored.
        let cut = &text[..text.len() - 10];
        assert_eq!(read(cut).unwrap().rows.len(), 5);
        assert_eq!(read(cut).unwrap().end, None);
    }

    /// Every single-line change is caught at that line or the next: a
    /// flipped `fresh`, an edited metadata value, a deleted, duplicated or
    /// swapped row, an edited end line.
    #[test]
    fn a_changed_line_fails_its_checksum() {
        let text = small_log(5, true);
        let lines: Vec<&str> = text.lines().collect();
        let join = |ls: Vec<String>| ls.join("\n") + "\n";
        let owned = || lines.iter().map(|l| l.to_string()).collect::<Vec<_>>();
        let cases: Vec<(&str, Vec<String>, usize)> = vec![
            (
                "fresh flipped",
                {
                    let mut l = owned();
                    let mut fields: Vec<&str> = lines[4].split(',').collect();
                    fields[7] = if fields[7] == "0" { "1" } else { "0" };
                    l[4] = fields.join(",");
                    l
                },
                5,
            ),
            (
                "metadata edited",
                {
                    let mut l = owned();
                    l[1] = l[1].replacen("\"b\":1", "\"b\":2", 1);
                    l
                },
                2,
            ),
            (
                "row deleted",
                {
                    let mut l = owned();
                    l.remove(5);
                    l
                },
                6,
            ),
            (
                "row duplicated",
                {
                    let mut l = owned();
                    l.insert(5, l[4].clone());
                    l
                },
                6,
            ),
            (
                "rows swapped",
                {
                    let mut l = owned();
                    l.swap(4, 5);
                    l
                },
                5,
            ),
            (
                "end edited",
                {
                    let mut l = owned();
                    l[8] = l[8].replacen("5", "4", 1);
                    l
                },
                9,
            ),
        ];
        for (what, changed, line) in cases {
            assert_ne!(join(changed.clone()), text, "{what}: nothing changed");
            let err = read(&join(changed)).unwrap_err();
            assert!(err.starts_with(&format!("line {line}: ")), "{what}: {err}");
        }
    }

    /// The digest does not depend on key order; it is SHA-256 of the
    /// canonical text (FIPS 180-2's "abc" vector checks the hash itself).
    #[test]
    fn the_config_digest_is_sha256_of_sorted_compact_json() {
        let a = serde_json::json!({"b": {"y": 1, "x": [1.5, 1e-5]}, "a": "s"});
        let b: serde_json::Value =
            serde_json::from_str(r#"{"a": "s", "b": {"x": [1.5, 0.00001], "y": 1}}"#).unwrap();
        assert_eq!(config_sha256(&a), config_sha256(&b));
        assert_eq!(
            canonical(&a).to_string(),
            r#"{"a":"s","b":{"x":[1.5,0.00001],"y":1}}"#
        );
        assert_ne!(
            config_sha256(&a),
            config_sha256(&serde_json::json!({"a": "t"}))
        );
        assert_eq!(
            config_sha256(&serde_json::json!("abc")),
            // SHA-256 of the 5 bytes "abc" with its quotes.
            {
                use sha2::Digest;
                let d = sha2::Sha256::digest(b"\"abc\"");
                d.iter().map(|b| format!("{b:02x}")).collect::<String>()
            }
        );
        use sha2::Digest;
        let abc = sha2::Sha256::digest(b"abc");
        assert_eq!(
            abc.iter().map(|b| format!("{b:02x}")).collect::<String>(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn dates_are_utc_civil_dates() {
        assert_eq!(iso8601_utc(0.0), "1970-01-01T00:00:00.000Z");
        assert_eq!(iso8601_utc(951_782_400.5), "2000-02-29T00:00:00.500Z");
        assert_eq!(iso8601_utc(1_795_392_000.0), "2026-11-23T00:00:00.000Z");
        assert_eq!(iso8601_utc(-1.0), "1969-12-31T23:59:59.000Z");
    }

    #[test]
    fn the_metadata_is_one_line_with_every_column() {
        let info = RunInfo {
            source: Source::Rig,
            config: serde_json::json!({"note": "a\nb"}),
            resolved: serde_json::Value::Null,
            git_commit: None,
            start_unix_s: 0.0,
            loop_settings: serde_json::Value::Null,
        };
        let mut out = Vec::new();
        write_header(&mut out, &metadata(&info)).unwrap();
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[0], FORMAT_LINE);
        let meta = check_json_line(lines[1], &mut Checksum::new()).unwrap();
        assert_eq!(meta["columns"].as_array().unwrap().len(), COLUMNS.len());
        assert_eq!(meta["config"]["note"], "a\nb");
        assert_eq!(meta["config_sha256"], config_sha256(&info.config));
        assert_eq!(lines[2], header_row());
    }
}
