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
