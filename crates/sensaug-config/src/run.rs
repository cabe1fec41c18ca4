//! What runs from a resolved configuration: the core's protocol and the
//! robot's controller built from it, a simulated trial with its log kept in
//! memory, the controller re-run over a recorded trial, and the metadata a
//! log of any run records (the configuration's serialisation). The binding,
//! the replay and `sensaug-rt` build these here, not each by hand.

use crate::error::ConfigError;
use crate::Resolved;
use sensaug_core::controller::{Robot, RobotCounters};
use sensaug_core::protocol::Protocol;
use sensaug_core::replay::replay_recorded;
use sensaug_core::row::Row;
use sensaug_core::world::{check_log_memory, log_budget, LogTooLarge, RunSummary, Scenario};
use sensaug_log::{push_record, RunInfo, Source, RECORD_BYTES};

/// The core refused a configuration that resolved: a bug, not the user's,
/// since resolving ran the same set-up checks. Names what it refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rejected(pub &'static str);

impl From<Rejected> for ConfigError {
    fn from(e: Rejected) -> Self {
        let message = "the core rejected a configuration that resolved; please report this";
        ConfigError::new(e.0, message)
    }
}

/// Why a simulated trial did not run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrialError {
    /// Its log would take more memory than it may, or the system refused
    /// to reserve it.
    TooLarge(LogTooLarge),
    /// See [`Rejected`].
    Rejected(Rejected),
}

impl From<Rejected> for TrialError {
    fn from(e: Rejected) -> Self {
        TrialError::Rejected(e)
    }
}

/// A simulated trial, run whole ([`Resolved::simulate`]).
pub struct SimulatedTrial {
    /// The log's rows as packed records ([`sensaug_log::push_record`]).
    pub records: Vec<u8>,
    /// The run's counters.
    pub summary: RunSummary,
    /// The log's metadata line ([`Resolved::log_metadata`]).
    pub meta: serde_json::Value,
}

/// The memory a simulated trial's log may take now: half of what is
/// available (`log_budget`); `None` where that is unknown.
pub fn trial_memory_budget() -> Option<u64> {
    sensaug_log::available_bytes().map(log_budget)
}

impl Resolved {
    /// The core's protocol of the phases.
    pub fn protocol(&self) -> Result<Protocol<'_>, Rejected> {
        Protocol::new(&self.phases(), self.dt_s).map_err(|_| Rejected("phases"))
    }

    /// The robot's controller, as the loop runs it and the replay re-runs it.
    pub fn controller(&self) -> Result<Robot<'_>, Rejected> {
        Robot::new(self.robot, self.protocol()?).map_err(|_| Rejected("robot"))
    }

    /// The robot's controller re-run over a recorded trial's rows
    /// ([`replay_recorded`]; with `applied`, the estimators predict with the
    /// recorded `u`, as on a rig): the replayed rows and the counters.
    pub fn replay(
        &self,
        recorded: &[Row],
        applied: bool,
    ) -> Result<(Vec<Row>, RobotCounters), Rejected> {
        let mut robot = self.controller()?;
        let mut rows = vec![Row::UNKNOWN; recorded.len()];
        let counters = replay_recorded(&mut robot, self.dt_s, recorded, applied, &mut rows);
        // The one set-up check, one row out per row in, holds by construction.
        Ok((rows, counters.map_err(|_| Rejected("replay"))?))
    }

    /// The metadata line of a log of this configuration's run, starting now
    /// (`sensaug_log::metadata`): the file's values, [`Resolved::derived`],
    /// `loop_settings` (a rig run's, else `Null`) and the git commit.
    pub fn log_metadata(
        &self,
        source: Source,
        git_commit: Option<String>,
        loop_settings: serde_json::Value,
    ) -> serde_json::Value {
        sensaug_log::metadata(&RunInfo {
            source,
            config: serde_json::to_value(&self.spec).unwrap_or_default(),
            resolved: self.derived(),
            git_commit,
            start_unix_s: sensaug_log::now_unix_s(),
            loop_settings,
        })
    }

    /// `(ticks, bytes)` of the simulated trial's log, one packed record per
    /// tick; `TooLarge` when more than `budget_bytes` (`None`: no limit).
    pub fn trial_memory(&self, budget_bytes: Option<u64>) -> Result<(u64, u64), TrialError> {
        let (protocol, bytes) = self.checked_log(budget_bytes.unwrap_or(u64::MAX))?;
        Ok((protocol.total_ticks(), bytes))
    }

    /// The protocol and the bytes of its log, within `budget_bytes`.
    fn checked_log(&self, budget_bytes: u64) -> Result<(Protocol<'_>, u64), TrialError> {
        let protocol = self.protocol()?;
        let bytes = check_log_memory(&protocol, RECORD_BYTES, budget_bytes);
        Ok((protocol, bytes.map_err(TrialError::TooLarge)?))
    }

    /// Runs the simulated trial whole, each tick's row packed as the tick
    /// ends into the one buffer of records (no buffer of rows between),
    /// whose size is checked against `budget_bytes` first (`None`: half the
    /// memory available, `log_budget`; no limit where that is unknown).
    pub fn simulate(
        &self,
        budget_bytes: Option<u64>,
        git_commit: Option<String>,
    ) -> Result<SimulatedTrial, TrialError> {
        let budget = budget_bytes.or_else(trial_memory_budget);
        let (protocol, bytes) = self.checked_log(budget.unwrap_or(u64::MAX))?;
        let scenario = Scenario::new(&self.phases(), self.robot, self.partner, self.world);
        let mut scenario = scenario.map_err(|_| Rejected("scenario"))?;
        // Reserved fallibly: where the budget is unknown, or the system
        // refuses, the trial still fails with a message.
        let mut records = Vec::new();
        usize::try_from(bytes)
            .ok()
            .and_then(|n| records.try_reserve_exact(n).ok())
            .ok_or_else(|| TrialError::TooLarge(LogTooLarge::new(&protocol, RECORD_BYTES, None)))?;
        let meta = self.log_metadata(Source::Simulation, git_commit, serde_json::Value::Null);
        let summary = scenario.run_with(|row| push_record(row, &mut records));
        Ok(SimulatedTrial {
            records,
            summary,
            meta,
        })
    }
}
