//! The tables for a person at the rig: `[display]` (what the participant's
//! monitor draws) and `[session]` (blocks of trials run from one plan file).
//! Neither changes the trial itself: the simulation and `sensaug-rt` read
//! them and ignore them; the Python session runner and display use them
//! (docs/person.md).

use crate::error::ConfigError;
use crate::schema::ScenarioSpec;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Most blocks in one session plan.
pub const MAX_BLOCKS: usize = 64;

/// Which way a positive handle position moves the cursor on the screen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ScreenDirection {
    /// Positive positions to the right of the screen's centre.
    Right,
    /// Positive positions to the left.
    Left,
    /// Positive positions above the centre.
    Up,
    /// Positive positions below the centre.
    Down,
}

/// What the rig does when the participant's display stops drawing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum OnFreeze {
    /// End the trial with the controlled stop (required with a person).
    Stop,
    /// Record the freeze in the display log and let the trial run on
    /// (allowed only with the virtual human: nobody is looking).
    Continue,
}

/// `[display]`: the participant's monitor (docs/person.md). Positions are in
/// the controller's position unit (`rig.position_unit`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DisplaySpec {
    /// Open the display with `sensaug rig`, `demo` and `session`.
    pub enabled: bool,
    /// Full screen on the rig's monitor; false: a window of width_px x height_px.
    pub fullscreen: bool,
    /// Window width (px) when not full screen.
    #[schemars(range(min = 64, max = 16384))]
    pub width_px: u32,
    /// Window height (px) when not full screen.
    #[schemars(range(min = 64, max = 16384))]
    pub height_px: u32,
    /// Scale: pixels per position unit (px per deg in the Hi5 presets).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 10000.0))]
    pub px_per_unit: f64,
    /// Which way a positive position moves the cursor: "right", "left",
    /// "up" or "down".
    pub direction: ScreenDirection,
    /// Visual noise: number of dots drawn around the target in integration
    /// phases when sigma_v > 0.
    #[schemars(range(min = 1, max = 1000))]
    pub dots: u32,
    /// Visual noise: std of the dots around the true target (position
    /// unit); 0 draws one target. Applies in integration phases.
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub sigma_v: f64,
    /// Visual noise: the dots are re-drawn every refresh_ms (ms).
    #[schemars(range(min = 1.0, max = 10000.0))]
    pub refresh_ms: f64,
    /// Seed of the dots: the n-th refresh's dots are a function of (seed,
    /// n), so a trial can be re-rendered exactly offline.
    pub seed: u64,
    /// The display counts as frozen when it has drawn no frame for this
    /// long (ms); the session then acts as on_freeze says.
    #[schemars(range(min = 20.0, max = 10000.0))]
    pub freeze_timeout_ms: f64,
    /// On a frozen display: "stop" (the controlled stop) or "continue"
    /// (only with rig.virtual_human = true).
    pub on_freeze: OnFreeze,
}

impl Default for DisplaySpec {
    fn default() -> Self {
        DisplaySpec {
            enabled: false,
            fullscreen: true,
            width_px: 1280,
            height_px: 720,
            px_per_unit: 25.0,
            direction: ScreenDirection::Right,
            dots: 20,
            sigma_v: 0.0,
            refresh_ms: 100.0,
            seed: 0,
            freeze_timeout_ms: 250.0,
            on_freeze: OnFreeze::Stop,
        }
    }
}

/// How the session orders its counterbalanced blocks per participant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum BlockOrder {
    /// As listed.
    Fixed,
    /// Row (participant number mod rows) of a balanced Latin square
    /// (Williams design: each block follows every other once).
    LatinSquare,
    /// A shuffle seeded by session.seed and the participant number.
    Shuffle,
}

/// `[[session.blocks]]`: one condition, run `trials` times.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BlockSpec {
    /// Name (in the manifest and the file names).
    #[schemars(length(min = 1, max = 64))]
    pub name: String,
    /// Trials in the block.
    #[schemars(range(min = 1, max = 10000))]
    pub trials: u32,
    /// The condition: fields of the trial configuration set for this block,
    /// by dotted path (as in `sensaug sweep`), e.g.
    /// `{ "partner.gains.lhh" = 1.5, "display.sigma_v" = 2.0 }`.
    #[serde(default)]
    pub set: BTreeMap<String, serde_json::Value>,
    /// A practice block: run first, in listed order, and repeated while the
    /// experimenter asks for it (unattended: once); its trials are in the
    /// manifest, marked practice.
    #[serde(default)]
    pub practice: bool,
    /// Only this block's phases run (by index into phases); empty: all.
    #[serde(default)]
    #[schemars(length(max = 4))]
    pub phases: Vec<u32>,
}

/// `[session]`: a plan of blocks of trials for `sensaug session`
/// (docs/person.md). The rest of the file is the base trial.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SessionSpec {
    /// The blocks; practice blocks first, then the others in `order`.
    #[schemars(length(min = 1, max = MAX_BLOCKS))]
    pub blocks: Vec<BlockSpec>,
    /// Order of the non-practice blocks per participant: "fixed",
    /// "latin_square" or "shuffle".
    #[serde(default = "default_order")]
    pub order: BlockOrder,
    /// Seed of the shuffle and of the trials: trial j of a block runs with
    /// seed + j (world.seed = it, robot.seed and partner.integration.seed
    /// offset as in `sensaug sweep`) unless the block sets a seed.
    #[serde(default)]
    pub seed: u64,
    /// Run on the virtual rig (sensaug-rt, true) or simulated (false).
    #[serde(default = "default_true")]
    pub rig: bool,
    /// Rest after each block (s), with a prompt on the display; 0: none.
    #[serde(default)]
    #[schemars(range(min = 0.0, max = 3600.0))]
    pub rest_s: f64,
    /// Questions asked after each block (answers in the manifest's
    /// questionnaire file); empty: none.
    #[serde(default)]
    #[schemars(length(max = 32))]
    pub questionnaire: Vec<String>,
}

fn default_order() -> BlockOrder {
    BlockOrder::Fixed
}

fn default_true() -> bool {
    true
}

/// The cross-field rules of `[display]` and `[session]`.
pub fn check(spec: &ScenarioSpec) -> Result<(), ConfigError> {
    let d = &spec.display;
    if d.on_freeze == OnFreeze::Continue && !spec.rig.virtual_human {
        return Err(ConfigError::new(
            "display.on_freeze",
            "\"continue\" is for the virtual human only: a person following a frozen screen \
             must be stopped; use \"stop\"",
        ));
    }
    let Some(session) = &spec.session else {
        return Ok(());
    };
    let mut names = std::collections::BTreeSet::new();
    for (i, block) in session.blocks.iter().enumerate() {
        let at = format!("session.blocks[{i}]");
        if !block
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(ConfigError::new(
                format!("{at}.name"),
                format!(
                    "{:?} is used in file names: use letters, digits, '_' and '-' only",
                    block.name
                ),
            ));
        }
        if !names.insert(block.name.as_str()) {
            return Err(ConfigError::new(
                format!("{at}.name"),
                format!("{:?} names two blocks; give each its own name", block.name),
            ));
        }
        for (j, &p) in block.phases.iter().enumerate() {
            if p as usize >= spec.phases.len() {
                return Err(ConfigError::new(
                    format!("{at}.phases[{j}]"),
                    format!(
                        "{p} is not a phase index: the base trial has {} phases (0..{})",
                        spec.phases.len(),
                        spec.phases.len() - 1
                    ),
                ));
            }
            if block.phases[..j].contains(&p) {
                return Err(ConfigError::new(
                    format!("{at}.phases[{j}]"),
                    format!("phase {p} is listed twice; list each phase once, in order"),
                ));
            }
        }
    }
    if session.blocks.iter().all(|b| b.practice) {
        return Err(ConfigError::new(
            "session.blocks",
            "every block is a practice block; add a block with practice = false",
        ));
    }
    Ok(())
}

/// Seed fields a session trial sets from its seed `s` (`session.seed` + its
/// index in the block), and their offsets: as `sensaug.sweep.SEED_FIELDS`
/// (`partner.integration.seed` only when the partner integrates goals).
pub const SEED_FIELDS: [(&str, u64); 3] = [
    ("world.seed", 0),
    ("robot.seed", 1_000_003),
    ("partner.integration.seed", 2_000_003),
];

/// Every block of a plan's `[session]` expanded as `sensaug session` runs it
/// and validated as a whole trial configuration: the base trial without
/// `[session]`, only the block's `phases`, the condition's fields `set` by
/// dotted path (as `sensaug sweep`: `a.b[2].c`, `[*]` for every element,
/// `lhx`/`lhv`/`lhh` for `partner.gains`), and the seed fields of the
/// block's first and last trial. Both checkers (`sensaug check`,
/// `sensaug-rt --check`) run it; a plan without `[session]` passes.
///
/// Errors name the block's condition and then the path or field, as
/// `sensaug.session.expand` does: `session.blocks[2].set: partner.gainz.lhh:
/// partner.gainz is not a field ...` for a path the configuration does not
/// have, `session.blocks[2].set: partner.gains[2]: ...` for a bad value.
pub fn check_conditions(spec: &ScenarioSpec) -> Result<(), ConfigError> {
    let Some(session) = &spec.session else {
        return Ok(());
    };
    let mut base = serde_json::to_value(spec)
        .map_err(|e| ConfigError::new("(config)", format!("cannot be represented: {e}")))?;
    if let Some(tables) = base.as_object_mut() {
        tables.remove("session");
    }
    for (i, block) in session.blocks.iter().enumerate() {
        let at = format!("session.blocks[{i}]");
        let mut trial = base.clone();
        if !block.phases.is_empty() {
            let phases = &base["phases"];
            trial["phases"] = block
                .phases
                .iter()
                .map(|&p| phases[p as usize].clone())
                .collect();
        }
        for (path, value) in &block.set {
            set_path(&mut trial, path, value)
                .map_err(|why| ConfigError::new(format!("{at}.set"), format!("{path}: {why}")))?;
        }
        let last = u64::from(block.trials.max(1) - 1);
        for k in [0, last] {
            let mut seeded = trial.clone();
            for (field, offset) in SEED_FIELDS {
                let seed = session
                    .seed
                    .checked_add(k)
                    .and_then(|s| s.checked_add(offset));
                if block.set.contains_key(field) {
                    continue;
                }
                let Some(seed) = seed else {
                    return Err(ConfigError::new(
                        "session.seed",
                        format!(
                            "{}: trial {k}'s {field} would overflow 2^64; choose a smaller seed",
                            session.seed
                        ),
                    ));
                };
                // partner.integration absent: no seed to set.
                let _ = set_path(&mut seeded, field, &serde_json::Value::from(seed));
            }
            crate::load_str(&seeded.to_string(), crate::Format::Json)
                .map_err(|e| ConfigError::new(format!("{at}.set"), e.to_string()))?;
        }
    }
    Ok(())
}

/// One segment of a dotted path: a field name, an index, or `[*]`.
#[derive(Debug, PartialEq)]
enum Segment<'a> {
    Field(&'a str),
    Index(usize),
    Every,
}

fn segments(path: &str) -> Result<Vec<Segment<'_>>, String> {
    let bad =
        || "not a dotted path of the configuration (e.g. robot.stage3.channel.gate)".to_string();
    let mut out = Vec::new();
    for part in path.split('.') {
        let (name, mut rest) = part.split_at(part.find('[').unwrap_or(part.len()));
        let ok = name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !ok {
            return Err(bad());
        }
        out.push(Segment::Field(name));
        while !rest.is_empty() {
            let close = rest.find(']').ok_or_else(bad)?;
            let inner = rest
                .get(1..close)
                .filter(|_| rest.starts_with('['))
                .ok_or_else(bad)?;
            out.push(match inner {
                "*" => Segment::Every,
                n => Segment::Index(n.parse().map_err(|_| bad())?),
            });
            rest = &rest[close + 1..];
        }
    }
    Ok(out)
}

/// Sets the field at dotted `path` of a configuration's JSON (as
/// `sensaug.sweep.set_path`); the reason when the path names no field.
fn set_path(
    root: &mut serde_json::Value,
    path: &str,
    value: &serde_json::Value,
) -> Result<(), String> {
    assign(root, &segments(path)?, value, "")
}

fn assign(
    node: &mut serde_json::Value,
    segs: &[Segment<'_>],
    value: &serde_json::Value,
    done: &str,
) -> Result<(), String> {
    use serde_json::Value;
    let Some((head, rest)) = segs.split_first() else {
        *node = value.clone();
        return Ok(());
    };
    // Gains by name: partner.gains.lhh is partner.gains[2].
    let head = match (head, &*node) {
        (Segment::Field(n), Value::Array(_)) if GAIN_NAMES.contains(n) => {
            Segment::Index(GAIN_NAMES.iter().position(|g| g == n).unwrap_or(0))
        }
        (Segment::Field(n), _) => Segment::Field(n),
        (Segment::Index(i), _) => Segment::Index(*i),
        (Segment::Every, _) => Segment::Every,
    };
    match (head, node) {
        (Segment::Every, Value::Array(items)) => {
            for (i, item) in items.iter_mut().enumerate() {
                assign(item, rest, value, &format!("{done}[{i}]"))?;
            }
            Ok(())
        }
        (Segment::Every, _) => Err(format!("{done} is not a list; [*] needs one")),
        (Segment::Index(i), Value::Array(items)) if i < items.len() => {
            assign(&mut items[i], rest, value, &format!("{done}[{i}]"))
        }
        (Segment::Index(i), _) => Err(format!(
            "{done}[{i}] does not exist (index out of range or not a list)"
        )),
        (Segment::Field(name), Value::Object(fields)) => {
            let here = if done.is_empty() {
                name.to_string()
            } else {
                format!("{done}.{name}")
            };
            match fields.get_mut(name) {
                Some(Value::Null) | None if !rest.is_empty() => Err(format!(
                    "{here} is not a field of the configuration, or an optional one the base \
                     leaves unset (give it a value first); see `sensaug schema`"
                )),
                Some(child) => assign(child, rest, value, &here),
                // An optional field the base leaves out; a name the schema
                // does not have is refused when the trial is read.
                None => {
                    fields.insert(name.to_string(), value.clone());
                    Ok(())
                }
            }
        }
        (Segment::Field(name), _) => Err(format!(
            "{done}.{name} is not a field of the configuration; see `sensaug schema`"
        )),
    }
}

/// `partner.gains` by name.
const GAIN_NAMES: [&str; 3] = ["lhx", "lhv", "lhh"];
