//! The master: set-up over SDO, the controlword state machine, one RPDO +
//! SYNC per tick, feedback from TPDOs, EMCY and heartbeats.
//!
//! Life cycle: [`Master::new`] (checks the settings) -> [`Master::boot`]
//! (waits for the drive, SDO set-up and checks, starts its own heartbeat,
//! NMT start) -> [`Master::enable`] (statusword-driven transitions to
//! OperationEnabled at zero torque) -> per tick [`Master::tick`] then, before
//! the next, [`Master::drain`] -> [`Master::shut_down`] (or
//! [`Master::quick_stop`] first). `boot`, `enable` and `shut_down` wait on
//! the bus; `tick` and `drain` never wait and never allocate.

use std::time::{Duration, Instant, SystemTime};

use super::frames::{self, Emcy, NmtCommand, NmtState, SdoResponse};
use super::od::{self, CanopenNode, Object, PdoMapping};
use super::state::{controlword, decode_statusword, next_controlword, DriveState, Goal};
use super::units::Units;
use super::Cia402Error;
use crate::frame::Frame;
use crate::transport::Transport;

/// How the master and the drive watch each other.
#[derive(Clone, Copy, Debug)]
pub struct MasterSettings {
    /// The drive's node-ID.
    pub node: CanopenNode,
    /// The master's own node-ID (its heartbeat's COB-ID is 0x700 + this).
    pub master_node: CanopenNode,
    /// The master's heartbeat period (producer). Must be shorter than
    /// `drive_consumer_ms`.
    pub heartbeat_period: Duration,
    /// Written to the drive's 0x1016:01: the drive faults when the master's
    /// heartbeat is missing this long (its command watchdog). 1..=65535 ms.
    pub drive_consumer_ms: u16,
    /// Written to the drive's 0x1017: its heartbeat period.
    pub drive_producer_ms: u16,
    /// The master reports the drive lost ([`Feedback::drive_heartbeat_lost`])
    /// when its heartbeat is missing this long (its heartbeat consumer).
    pub drive_heartbeat_timeout: Duration,
    /// Longest wait for one SDO answer or one state transition at set-up.
    pub response_timeout: Duration,
    /// The torque limit the drive must hold in 0x6072 (max torque), N m:
    /// set-up refuses a drive whose 0x6072 is another value
    /// ([`Cia402Error::MaxTorqueMismatch`]), higher or lower.
    pub max_torque_nm: f64,
    /// How a TPDO is matched to the SYNC it answers: chosen from the drive's
    /// dictionary at set-up, or forced.
    pub freshness: FreshnessSetting,
}

/// How the master matches a TPDO to the SYNC it answers (docs/cia402.md,
/// "Freshness").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Freshness {
    /// The drive echoes each SYNC's counter in 0x2000, mapped last in both
    /// TPDOs: a late or replayed TPDO is told by its counter.
    SyncCounterEcho,
    /// A standard drive (no 0x2000): a TPDO received after SYNC k and before
    /// SYNC k+1 answers SYNC k (by its kernel receive time where the
    /// transport has one, else by when the master reads it); one TPDO of
    /// each kind per SYNC, a second is a duplicate and makes that SYNC's
    /// answer ambiguous. A replay inside the window is not detected.
    Standard,
}

impl Freshness {
    /// Its name in the configuration and the statistics.
    pub fn name(self) -> &'static str {
        match self {
            Self::SyncCounterEcho => "sync_counter_echo",
            Self::Standard => "standard",
        }
    }
}

/// [`MasterSettings::freshness`]: the mode, or how set-up chooses it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FreshnessSetting {
    /// Set-up reads 0x2000: the echo if the drive has it, standard if the
    /// drive answers "object does not exist".
    Auto,
    /// The echo; a drive without 0x2000 is refused
    /// ([`Cia402Error::NoSyncCounterEcho`]).
    SyncCounterEcho,
    /// Standard, even on a drive that has 0x2000 (its TPDOs are mapped
    /// without it).
    Standard,
}

impl MasterSettings {
    /// Node 1, master 127; master heartbeat every 10 ms, the drive's
    /// watchdog 100 ms, its heartbeat every 50 ms, lost after 100 ms; max
    /// torque 3 N m (the EDS's 3000 per-mille of 1 N m).
    pub fn new(node: CanopenNode) -> Self {
        let drive_heartbeat_timeout = Duration::from_millis(100);
        Self {
            node,
            // Constant in range.
            master_node: CanopenNode::new(127).unwrap_or(node),
            heartbeat_period: Duration::from_millis(10),
            drive_consumer_ms: 100,
            drive_producer_ms: producer_for(drive_heartbeat_timeout),
            drive_heartbeat_timeout,
            response_timeout: Duration::from_secs(2),
            max_torque_nm: 3.0,
            freshness: FreshnessSetting::Auto,
        }
    }

    /// Watches the drive's heartbeat with consumer time `timeout`, and has
    /// the drive beat twice per timeout ([`producer_for`]).
    pub fn with_drive_heartbeat_timeout(mut self, timeout: Duration) -> Self {
        self.drive_heartbeat_timeout = timeout;
        self.drive_producer_ms = producer_for(timeout);
        self
    }

    fn validate(&self) -> Result<(), Cia402Error> {
        if self.node == self.master_node {
            return Err(Cia402Error::BadParameter {
                field: "master_node",
                value: u64::from(self.master_node.get()),
                why: "must differ from the drive's node",
            });
        }
        if self.drive_consumer_ms == 0
            || Duration::from_millis(u64::from(self.drive_consumer_ms)) <= self.heartbeat_period
        {
            return Err(Cia402Error::BadParameter {
                field: "drive_consumer_ms",
                value: u64::from(self.drive_consumer_ms),
                why: "must be > 0 and longer than heartbeat_period (else the drive faults)",
            });
        }
        if self.heartbeat_period.is_zero() {
            return Err(Cia402Error::BadParameter {
                field: "heartbeat_period",
                value: 0,
                why: "must be > 0",
            });
        }
        let producer = Duration::from_millis(u64::from(self.drive_producer_ms));
        if self.drive_producer_ms == 0 || producer >= self.drive_heartbeat_timeout {
            return Err(Cia402Error::BadParameter {
                field: "drive_producer_ms",
                value: u64::from(self.drive_producer_ms),
                why: "must be > 0 and shorter than drive_heartbeat_timeout",
            });
        }
        // A finite limit of 0 or below matches no drive's 0x6072 (>= 1): set-up refuses it.
        if !self.max_torque_nm.is_finite() {
            return Err(Cia402Error::NotFinite {
                field: "max_torque_nm",
            });
        }
        Ok(())
    }
}

/// The shortest drive consumer time (0x1016, ms) a master takes: its own
/// heartbeat period is at least 1 ms and must be shorter
/// ([`MasterSettings::drive_consumer_ms`]).
pub const DRIVE_CONSUMER_MS_MIN: u16 = 2;

/// The drive's heartbeat period (0x1017, ms) for a master that declares it
/// lost after `timeout`: half of it (at least 1 ms), so one late beat is
/// not a loss.
pub fn producer_for(timeout: Duration) -> u16 {
    u16::try_from(timeout.as_millis() / 2)
        .unwrap_or(u16::MAX)
        .max(1)
}

/// What the master knows about the drive, updated by every received frame.
#[derive(Clone, Copy, Debug, Default)]
pub struct Feedback {
    /// Last statusword (TPDO1).
    pub statusword: u16,
    /// Decoded from it (None before the first TPDO1, or for an invalid
    /// statusword).
    pub state: Option<DriveState>,
    /// Position actual, shaft rad.
    pub position_rad: f64,
    /// Velocity actual, shaft rad/s.
    pub velocity_rad_s: f64,
    /// Torque actual, N m.
    pub torque_nm: f64,
    /// TPDO1 frames received.
    pub tpdo1_received: u64,
    /// TPDO2 frames received.
    pub tpdo2_received: u64,
    /// The SYNC counter the last TPDO1 echoed (0x2000).
    pub tpdo1_sync_counter: u8,
    /// The SYNC counter the last TPDO2 echoed (0x2000).
    pub tpdo2_sync_counter: u8,
    /// The last EMCY (code 0: the drive's error reset).
    pub last_emcy: Option<Emcy>,
    /// EMCY frames received.
    pub emcy_received: u64,
    /// The NMT state of the drive's last heartbeat or boot-up.
    pub drive_nmt: Option<NmtState>,
    /// Heartbeats (and boot-ups) received from the drive.
    pub heartbeats_received: u64,
    /// True once the drive's heartbeat has been missing longer than
    /// `drive_heartbeat_timeout` (checked by [`Master::drain`]).
    pub drive_heartbeat_lost: bool,
    /// Frames from the drive that did not decode.
    pub decode_errors: u64,
    /// Frames only a master sends to this drive (its RPDO1, an SDO request
    /// to it, SYNC, NMT to it or to all): another master is on the bus
    /// (a socket never receives its own frames).
    pub foreign_commands: u64,
    /// TPDOs discarded because they answer an older SYNC than the TPDO of
    /// the same kind already taken, or the same SYNC again (a duplicate, a
    /// late copy, a replay): the newest SYNC counter wins (echo mode).
    pub tpdos_discarded: u64,
    /// Standard mode: TPDOs received (kernel time) before the last SYNC was
    /// sent but read after it: a late answer to an earlier SYNC, not taken.
    /// Needs kernel receive timestamps (SocketCAN and the UDP bus both
    /// give them).
    pub tpdos_late: u64,
    /// Standard mode: a second TPDO of one kind after one SYNC, not taken
    /// (a late answer to the SYNC before, a copy, a second sender); the
    /// SYNC's answer is ambiguous.
    pub tpdos_duplicated: u64,
    /// SYNCs followed by the next SYNC without a TPDO1 and a TPDO2 taken
    /// for them (both modes; set-up's and the stop's SYNCs included).
    pub syncs_unanswered: u64,
    /// What said the drive reset after NMT start, the first such report: a
    /// boot-up message, or a heartbeat other than OPERATIONAL after an
    /// OPERATIONAL one.
    pub reset: Option<NmtState>,
}

/// One EMCY as received: the frame and when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EmcyRecord {
    /// The EMCY.
    pub emcy: Emcy,
    /// When it was taken in.
    pub at: Instant,
}

/// EMCYs kept per run by [`Master::emcy_records`] (allocated up front; later
/// ones are only counted in [`Feedback::emcy_received`]).
pub const EMCY_RECORDS: usize = 64;

/// What [`Master::absorb`] made of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Heard {
    /// The drive's TPDO2: with the TPDO1 before it, one tick's feedback.
    Tpdo2,
    /// A frame only a master sends ([`Feedback::foreign_commands`]).
    ForeignCommand,
    /// A frame from the drive that did not decode.
    Undecodable,
    /// A TPDO discarded: it answers an older SYNC than the one already
    /// taken, or the same one again ([`Feedback::tpdos_discarded`]), or
    /// (standard mode) it was received before the last SYNC
    /// ([`Feedback::tpdos_late`]).
    Discarded,
    /// Standard mode: a second TPDO of its kind after the last SYNC
    /// ([`Feedback::tpdos_duplicated`]); not taken, and that SYNC's answer
    /// is ambiguous.
    Duplicated,
    /// A TPDO echoing the SYNC counter of the one of its kind already
    /// taken, with other values: two answers to one SYNC (a forger on the
    /// bus); not taken.
    Conflicting {
        /// The SYNC counter both echo.
        sync_counter: u8,
    },
    /// Any other frame (TPDO1, EMCY, heartbeat, or not from the drive).
    Other,
}

/// The CiA 402 master for one drive.
pub struct Master {
    settings: MasterSettings,
    units: Units,
    fb: Feedback,
    controlword: u16,
    next_heartbeat: Instant,
    last_drive_heartbeat: Option<Instant>,
    syncs_sent: u64,
    /// The counter of the last SYNC sent (0 before the first).
    sync_counter: u8,
    /// When the last SYNC was sent (`CLOCK_REALTIME`, the kernel receive
    /// timestamps' clock): standard mode's window start.
    last_sync_at: Option<SystemTime>,
    /// The mode set-up chose (None before [`Master::configure`]).
    freshness: Option<Freshness>,
    /// PDOs whose configuration set-up wrote (they differed from the EDS's).
    pdos_rewritten: u32,
    /// NMT start sent: a boot-up from now on is a reset.
    nmt_started: bool,
    /// An OPERATIONAL heartbeat seen since NMT start: another state from now
    /// on is a reset (before it, a beat sent before the start may arrive).
    operational_seen: bool,
    /// The EMCYs received, up to [`EMCY_RECORDS`] (capacity reserved by
    /// [`Master::new`]).
    emcy_records: Vec<EmcyRecord>,
    /// Torque commands beyond 0x6072 sent as +-0x6072.
    commands_clamped: u64,
    /// Non-finite torque commands sent as 0.
    commands_non_finite: u64,
}

impl Master {
    /// Checks the settings. Units are the EDS defaults until [`Master::boot`]
    /// reads the drive's.
    pub fn new(settings: MasterSettings) -> Result<Self, Cia402Error> {
        settings.validate()?;
        Ok(Self {
            settings,
            units: Units::eds_defaults(),
            fb: Feedback::default(),
            controlword: controlword::DISABLE_VOLTAGE,
            next_heartbeat: Instant::now(),
            last_drive_heartbeat: None,
            syncs_sent: 0,
            sync_counter: 0,
            last_sync_at: None,
            freshness: None,
            pdos_rewritten: 0,
            nmt_started: false,
            operational_seen: false,
            emcy_records: Vec::with_capacity(EMCY_RECORDS),
            commands_clamped: 0,
            commands_non_finite: 0,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &MasterSettings {
        &self.settings
    }

    /// The drive's units (read at boot).
    pub fn units(&self) -> &Units {
        &self.units
    }

    /// The feedback as of the last [`Master::drain`].
    pub fn feedback(&self) -> &Feedback {
        &self.fb
    }

    /// PDOs whose transmission type or mapping set-up wrote because the
    /// drive's differed from the EDS's.
    pub fn pdos_rewritten(&self) -> u32 {
        self.pdos_rewritten
    }

    /// SYNCs sent so far (one per tick and per set-up step).
    pub fn syncs_sent(&self) -> u64 {
        self.syncs_sent
    }

    /// The counter of the last SYNC sent (1..=240; 0 before the first).
    pub fn sync_counter(&self) -> u8 {
        self.sync_counter
    }

    /// When the last SYNC was sent (`CLOCK_REALTIME`, read just before the
    /// send; the clock of [`Transport::last_rx_time`]): None before the
    /// first.
    pub fn last_sync_at(&self) -> Option<SystemTime> {
        self.last_sync_at
    }

    /// How TPDOs are matched to SYNCs: chosen by [`Master::configure`]
    /// (None before).
    pub fn freshness(&self) -> Option<Freshness> {
        self.freshness
    }

    /// The EMCYs received so far (the first [`EMCY_RECORDS`]; all are
    /// counted in [`Feedback::emcy_received`]).
    pub fn emcy_records(&self) -> &[EmcyRecord] {
        &self.emcy_records
    }

    /// Torque commands beyond 0x6072 that [`Master::tick`] sent clamped.
    pub fn commands_clamped(&self) -> u64 {
        self.commands_clamped
    }

    /// Non-finite torque commands that [`Master::tick`] sent as 0.
    pub fn commands_non_finite(&self) -> u64 {
        self.commands_non_finite
    }

    /// Set-up: wait for the drive's boot-up or heartbeat; check it is a
    /// CiA 402 device; read the units and check its max torque 0x6072 is
    /// the configured limit; choose the freshness mode (the SYNC counter echo
    /// 0x2000 if the drive has it, unless forced; a refused drive is left as
    /// found: nothing was written yet);
    /// set cyclic synchronous torque mode and check the display; write the
    /// heartbeat times; check the PDO communication and mapping parameters,
    /// writing those that differ from the EDS's; start the master's
    /// heartbeat; NMT start the drive.
    pub fn boot(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        self.wait_for_drive(bus)?;
        self.configure(bus)
    }

    /// Set-up, listening only: waits for the drive's boot-up or heartbeat.
    pub fn wait_for_drive(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        let start = Instant::now();
        while self.fb.heartbeats_received == 0 {
            if start.elapsed() > self.settings.response_timeout {
                return Err(Cia402Error::Timeout {
                    what: "the drive's boot-up or heartbeat",
                    state: None,
                });
            }
            self.receive_one(bus, Duration::from_millis(10))?;
        }
        Ok(())
    }

    /// Set-up after [`Master::wait_for_drive`]: the rest of [`Master::boot`].
    pub fn configure(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        let s = self.settings;
        let device = self.sdo_read_u32(bus, od::DEVICE_TYPE)?;
        self.expect(od::DEVICE_TYPE, od::PROFILE_402, device & 0xFFFF)?;
        // Everything the master refuses a drive for is read before anything
        // is written: a refused drive is left as it was found.
        self.read_units(bus)?;
        self.check_max_torque()?;
        self.freshness = Some(self.choose_freshness(bus)?);
        self.sdo_write(
            bus,
            od::MODES_OF_OPERATION,
            &od::MODE_CYCLIC_SYNCHRONOUS_TORQUE.to_le_bytes(),
        )?;
        let display = self.sdo_read(bus, od::MODES_OF_OPERATION_DISPLAY)?;
        self.expect(
            od::MODES_OF_OPERATION_DISPLAY,
            od::MODE_CYCLIC_SYNCHRONOUS_TORQUE as u32,
            u32::from(display[0]),
        )?;
        self.sdo_write(
            bus,
            od::PRODUCER_HEARTBEAT,
            &s.drive_producer_ms.to_le_bytes(),
        )?;
        let consumer = (u32::from(s.master_node.get()) << 16) | u32::from(s.drive_consumer_ms);
        // The master's heartbeat must run before the drive's consumer is armed.
        self.send_heartbeat(bus, NmtState::PreOperational)?;
        self.sdo_write(bus, od::CONSUMER_HEARTBEAT, &consumer.to_le_bytes())?;
        self.check_pdos(bus)?;
        self.send_heartbeat(bus, NmtState::Operational)?;
        bus.send(&frames::nmt(NmtCommand::Start, s.node.get()))?;
        self.nmt_started = true;
        self.operational_seen = false;
        Ok(())
    }

    /// The drive's 0x6072 (read with the units) must be the configured
    /// limit in the drive's torque steps: a higher one would let the drive
    /// apply more than the configuration allows (e.g. another node wrote
    /// it), a lower one would reject the controller's commands.
    fn check_max_torque(&self) -> Result<(), Cia402Error> {
        let u = &self.units;
        let wanted = (self.settings.max_torque_nm / u.torque_step_nm()).round();
        if wanted == f64::from(u.max_torque_per_mille) {
            return Ok(());
        }
        Err(Cia402Error::MaxTorqueMismatch {
            drive_per_mille: u.max_torque_per_mille,
            drive_nm: u.max_torque_nm(),
            configured_nm: self.settings.max_torque_nm,
            configured_per_mille: wanted,
            rated_mnm: u.rated_torque_mnm,
        })
    }

    fn read_units(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        let rated = self.sdo_read_u32(bus, od::RATED_TORQUE)?;
        let max = self.sdo_read_u32(bus, od::MAX_TORQUE)?;
        let max = u16::try_from(max)
            .ok()
            .filter(|m| *m <= i16::MAX as u16)
            .ok_or(Cia402Error::BadParameter {
                field: "0x6072 max torque",
                value: u64::from(max),
                why: "must fit the INTEGER16 target torque (<= 32767 per-mille)",
            })?;
        let enc = (
            self.sdo_read_u32(bus, od::ENCODER_INCREMENTS)?,
            self.sdo_read_u32(bus, od::ENCODER_MOTOR_REVOLUTIONS)?,
        );
        let gear = (
            self.sdo_read_u32(bus, od::GEAR_MOTOR_REVOLUTIONS)?,
            self.sdo_read_u32(bus, od::GEAR_SHAFT_REVOLUTIONS)?,
        );
        self.units = Units::new(rated, max, enc, gear)?;
        Ok(())
    }

    /// The freshness mode ([`MasterSettings::freshness`]): forced standard
    /// reads nothing; otherwise 0x2000 is read, and a drive answering
    /// "object does not exist" is standard (auto) or refused with
    /// [`Cia402Error::NoSyncCounterEcho`] (echo forced).
    fn choose_freshness(&mut self, bus: &mut dyn Transport) -> Result<Freshness, Cia402Error> {
        let setting = self.settings.freshness;
        if setting == FreshnessSetting::Standard {
            return Ok(Freshness::Standard);
        }
        match self.sdo_read(bus, od::SYNC_COUNTER_ECHO) {
            Ok(_) => Ok(Freshness::SyncCounterEcho),
            Err(Cia402Error::SdoAbort { code, .. }) if code == od::SDO_ABORT_NO_OBJECT => {
                match setting {
                    FreshnessSetting::Auto => Ok(Freshness::Standard),
                    _ => Err(Cia402Error::NoSyncCounterEcho),
                }
            }
            Err(e) => Err(e),
        }
    }

    /// The PDO set of the mode chosen ([`od::PDOS`] with the echo,
    /// [`od::STANDARD_PDOS`] without).
    fn pdos(&self) -> [od::Pdo; 3] {
        match self.freshness {
            Some(Freshness::Standard) => od::STANDARD_PDOS,
            _ => od::PDOS,
        }
    }

    /// The drive must use the mode's PDO set ([`Master::pdos`]): the predefined
    /// COB-IDs (another COB-ID is a `Mismatch`: this master does not move
    /// PDOs), valid, transmission type 1 (every SYNC), the EDS's mappings. A
    /// PDO that is not valid or differs in transmission type or mapping is
    /// written with [`od::remap_writes`], then read back.
    fn check_pdos(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        let n = self.settings.node;
        for pdo in self.pdos() {
            let cob_id = self.sdo_read_u32(bus, pdo.cob_id)?;
            let flags = od::PDO_NOT_VALID | od::PDO_NO_RTR;
            self.expect(pdo.cob_id, (pdo.predefined_cob_id)(n), cob_id & !flags)?;
            let every_sync = u32::from(od::TRANSMISSION_EVERY_SYNC);
            let transmission = self.sdo_read_u32(bus, pdo.transmission)?;
            let mapped = match self.check_mapping(bus, &pdo.mapping) {
                Ok(()) => true,
                Err(Cia402Error::Mismatch { .. }) => false,
                Err(e) => return Err(e),
            };
            if cob_id & od::PDO_NOT_VALID == 0 && transmission == every_sync && mapped {
                continue;
            }
            for w in od::remap_writes(&pdo, cob_id) {
                self.sdo_write(bus, w.object, &w.bytes())?;
            }
            self.pdos_rewritten += 1;
            let transmission = self.sdo_read_u32(bus, pdo.transmission)?;
            self.expect(pdo.transmission, every_sync, transmission)?;
            self.check_mapping(bus, &pdo.mapping)?;
        }
        Ok(())
    }

    fn check_mapping(
        &mut self,
        bus: &mut dyn Transport,
        m: &PdoMapping,
    ) -> Result<(), Cia402Error> {
        let count = od::mapping_count_object(m.index);
        let got = self.sdo_read_u32(bus, count)?;
        self.expect(count, m.entries.len() as u32, got)?;
        for (i, &entry) in m.entries.iter().enumerate() {
            let o = od::mapping_entry_object(m.index, i);
            let got = self.sdo_read_u32(bus, o)?;
            self.expect(o, entry, got)?;
        }
        Ok(())
    }

    fn expect(&self, o: Object, expected: u32, got: u32) -> Result<(), Cia402Error> {
        if expected == got {
            Ok(())
        } else {
            Err(Cia402Error::Mismatch {
                object: o.name,
                index: o.index,
                subindex: o.subindex,
                expected,
                got,
            })
        }
    }

    /// Brings the drive to OperationEnabled at zero torque: one RPDO + SYNC
    /// per `step`, each controlword chosen from the last statusword (a
    /// Fault is reset once, on a rising edge of bit 7).
    /// Returns once the last SYNC sent has been answered, so the feedback is
    /// the enabled drive's.
    pub fn enable(&mut self, bus: &mut dyn Transport, step: Duration) -> Result<(), Cia402Error> {
        self.drive_towards(bus, step, Goal::Enabled, "OperationEnabled", |s| {
            s == DriveState::OperationEnabled
        })?;
        let start = Instant::now();
        while !self.last_sync_answered() {
            if start.elapsed() > self.settings.response_timeout {
                return Err(Cia402Error::Timeout {
                    what: "the TPDOs answering the enabling SYNCs",
                    state: self.fb.state,
                });
            }
            self.receive_one(bus, step)?;
        }
        Ok(())
    }

    /// The last TPDO1 and TPDO2 received both echo the counter of the last
    /// SYNC sent: the feedback is the answer to it, not a late answer to an
    /// earlier one or a replay (unless exactly a multiple of
    /// [`od::SYNC_COUNTER_OVERFLOW`] SYNCs old).
    pub fn last_sync_answered(&self) -> bool {
        self.syncs_sent > 0
            && self.fb.tpdo1_sync_counter == self.sync_counter
            && self.fb.tpdo2_sync_counter == self.sync_counter
    }

    fn drive_towards(
        &mut self,
        bus: &mut dyn Transport,
        step: Duration,
        goal: Goal,
        what: &'static str,
        done: impl Fn(DriveState) -> bool,
    ) -> Result<(), Cia402Error> {
        let start = Instant::now();
        loop {
            let state = self.fb.state.unwrap_or(DriveState::NotReadyToSwitchOn);
            if self.fb.tpdo1_received > 0 && done(state) {
                return Ok(());
            }
            if start.elapsed() > self.settings.response_timeout * 2 {
                return Err(Cia402Error::Timeout {
                    what,
                    state: self.fb.state,
                });
            }
            let cw = next_controlword(state, goal, self.controlword);
            self.send_cycle(bus, cw, 0)?;
            let until = Instant::now() + step;
            while let Some(left) = until.checked_duration_since(Instant::now()) {
                self.receive_one(bus, left)?;
            }
        }
    }

    /// One control tick: RPDO1 (enable operation, `torque_nm` as per-mille
    /// of rated torque) then SYNC, and the master's heartbeat when due. The
    /// master never falls silent: a torque beyond 0x6072 is sent as
    /// +-0x6072 and counted ([`Master::commands_clamped`]), a non-finite one
    /// as 0 ([`Master::commands_non_finite`]). The drive applies the torque
    /// at this SYNC and answers with TPDO1 and TPDO2. Does not wait, does
    /// not allocate.
    pub fn tick(&mut self, bus: &mut dyn Transport, torque_nm: f64) -> Result<(), Cia402Error> {
        let per_mille = match self.units.torque_to_per_mille(torque_nm) {
            Ok(t) => t,
            Err(Cia402Error::TorqueBeyondLimit { .. }) => {
                self.commands_clamped += 1;
                self.units.max_torque_per_mille_signed(torque_nm)
            }
            Err(_) => {
                self.commands_non_finite += 1;
                0
            }
        };
        self.send_cycle(bus, controlword::ENABLE_OPERATION, per_mille)
    }

    /// Quick stop: torque 0 at once (controlword 0x0002), with a SYNC.
    pub fn quick_stop(&mut self, bus: &mut dyn Transport) -> Result<(), Cia402Error> {
        self.send_cycle(bus, controlword::QUICK_STOP, 0)
    }

    fn send_cycle(
        &mut self,
        bus: &mut dyn Transport,
        cw: u16,
        per_mille: i16,
    ) -> Result<(), Cia402Error> {
        self.controlword = cw;
        if self.syncs_sent > 0 && !self.last_sync_answered() {
            self.fb.syncs_unanswered += 1;
        }
        // Each frame is sent even if the one before failed (a full queue):
        // the first error is returned.
        let rpdo = bus.send(&frames::rpdo1(self.settings.node, cw, per_mille));
        self.sync_counter = next_sync_counter(self.sync_counter);
        // Taken before the send: a frame the kernel received before this
        // time surely came before the SYNC (taken after, a preemption
        // between the send and the clock read would date a prompt answer
        // before its SYNC).
        let sync_at = SystemTime::now();
        let sync = bus.send(&frames::sync(self.sync_counter));
        self.last_sync_at = Some(sync_at);
        self.syncs_sent += 1;
        let heartbeat = if Instant::now() >= self.next_heartbeat {
            self.send_heartbeat(bus, NmtState::Operational)
        } else {
            Ok(())
        };
        rpdo?;
        sync?;
        heartbeat
    }

    fn send_heartbeat(&mut self, bus: &mut dyn Transport, s: NmtState) -> Result<(), Cia402Error> {
        bus.send(&frames::heartbeat(self.settings.master_node, s))?;
        let now = Instant::now();
        // Skip missed beats after a stall instead of bursting.
        self.next_heartbeat = (self.next_heartbeat + self.settings.heartbeat_period).max(now);
        Ok(())
    }

    /// Takes every frame already received into the feedback, without
    /// waiting; then checks the drive's heartbeat. Returns the number of
    /// frames read. Does not allocate.
    pub fn drain(&mut self, bus: &mut dyn Transport) -> Result<usize, Cia402Error> {
        let mut n = 0;
        while let Some(f) = bus.recv_ready()? {
            self.absorb_received(&f, bus.last_rx_time());
            n += 1;
        }
        self.check_drive_heartbeat(Instant::now());
        Ok(n)
    }

    /// Marks the drive's heartbeat lost when none came within
    /// [`MasterSettings::drive_heartbeat_timeout`] of `now` (after the
    /// first). [`Master::drain`] calls it; a caller that reads frames
    /// itself ([`Master::absorb`]) calls it once per tick.
    pub fn check_drive_heartbeat(&mut self, now: Instant) {
        if let Some(t) = self.last_drive_heartbeat {
            if now.duration_since(t) > self.settings.drive_heartbeat_timeout {
                self.fb.drive_heartbeat_lost = true;
            }
        }
    }

    fn receive_one(
        &mut self,
        bus: &mut dyn Transport,
        timeout: Duration,
    ) -> Result<(), Cia402Error> {
        if let Some(f) = bus.recv(timeout)? {
            self.absorb_received(&f, bus.last_rx_time());
        }
        Ok(())
    }

    /// Updates the feedback from one frame (frames not from the drive, or
    /// SDO responses outside a transfer, are ignored) and says what it was.
    /// Does not allocate. [`Master::absorb_received`] without a receive time.
    pub fn absorb(&mut self, f: &Frame) -> Heard {
        self.absorb_received(f, None)
    }

    /// [`Master::absorb`] with the frame's kernel receive time
    /// ([`Transport::last_rx_time`]), which standard mode uses to tell a
    /// TPDO received before the last SYNC (late) from an answer to it.
    pub fn absorb_received(&mut self, f: &Frame, received: Option<SystemTime>) -> Heard {
        if !f.is_standard_data() {
            return Heard::Other;
        }
        let n = self.settings.node;
        let to_node = |t: Option<&u8>| matches!(t, Some(&t) if t == 0 || t == n.get());
        if f.id == n.rpdo1()
            || f.id == n.sdo_rx()
            || f.id == od::SYNC_COB_ID
            || (f.id == od::NMT_COB_ID && to_node(f.payload().get(1)))
        {
            self.fb.foreign_commands += 1;
            return Heard::ForeignCommand;
        }
        let p = f.payload();
        let standard = self.freshness == Some(Freshness::Standard);
        let heard = if f.id == n.tpdo1() {
            let decoded = if standard {
                frames::decode_tpdo1_standard(p, self.sync_counter)
            } else {
                frames::decode_tpdo1(p)
            };
            decoded.map(|t| {
                self.fb.tpdo1_received += 1;
                if self.received_before_last_sync(received) {
                    return self.late();
                }
                let (taken, received) = (self.fb.tpdo1_sync_counter, self.fb.tpdo1_received);
                if !self.take(t.sync_counter, taken, received) {
                    let same = t.statusword == self.fb.statusword
                        && self.units.increments_to_rad(t.position_increments)
                            == self.fb.position_rad;
                    return self.discarded(t.sync_counter, taken, same);
                }
                self.fb.statusword = t.statusword;
                self.fb.tpdo1_sync_counter = t.sync_counter;
                self.fb.state = decode_statusword(t.statusword).ok();
                self.fb.position_rad = self.units.increments_to_rad(t.position_increments);
                Heard::Other
            })
        } else if f.id == n.tpdo2() {
            let decoded = if standard {
                frames::decode_tpdo2_standard(p, self.sync_counter)
            } else {
                frames::decode_tpdo2(p)
            };
            decoded.map(|t| {
                self.fb.tpdo2_received += 1;
                if self.received_before_last_sync(received) {
                    return self.late();
                }
                let (taken, received) = (self.fb.tpdo2_sync_counter, self.fb.tpdo2_received);
                if !self.take(t.sync_counter, taken, received) {
                    let same = self
                        .units
                        .increments_per_s_to_rad_s(t.velocity_increments_s)
                        == self.fb.velocity_rad_s
                        && self.units.per_mille_to_torque_nm(t.torque_per_mille)
                            == self.fb.torque_nm;
                    return self.discarded(t.sync_counter, taken, same);
                }
                self.fb.velocity_rad_s = self
                    .units
                    .increments_per_s_to_rad_s(t.velocity_increments_s);
                self.fb.torque_nm = self.units.per_mille_to_torque_nm(t.torque_per_mille);
                self.fb.tpdo2_sync_counter = t.sync_counter;
                Heard::Tpdo2
            })
        } else if f.id == n.emcy() {
            frames::decode_emcy(p).map(|e| {
                self.fb.emcy_received += 1;
                self.fb.last_emcy = Some(e);
                if self.emcy_records.len() < self.emcy_records.capacity() {
                    self.emcy_records.push(EmcyRecord {
                        emcy: e,
                        at: Instant::now(),
                    });
                }
                Heard::Other
            })
        } else if f.id == n.heartbeat() {
            frames::decode_heartbeat(p).map(|s| {
                self.fb.heartbeats_received += 1;
                self.fb.drive_nmt = Some(s);
                self.last_drive_heartbeat = Some(Instant::now());
                self.fb.drive_heartbeat_lost = false;
                self.note_nmt_state(s);
                Heard::Other
            })
        } else {
            return Heard::Other;
        };
        heard.unwrap_or_else(|_| {
            self.fb.decode_errors += 1;
            Heard::Undecodable
        })
    }

    /// Whether a TPDO echoing SYNC counter `echo` is taken: it answers a
    /// later SYNC than the one of the same kind already taken (echoing
    /// `taken`), counting back from the last SYNC sent. The newest wins; an
    /// older one or a repeat of the same counter is discarded and counted.
    /// `received` counts this kind's TPDOs, this one included: the first is
    /// always taken, as is any before the first SYNC.
    /// In standard mode the echo is the last SYNC's counter (the window the
    /// TPDO arrived in), so only a second TPDO in one window is not newer.
    fn take(&self, echo: u8, taken: u8, received: u64) -> bool {
        let age = |c: u8| syncs_ago(self.sync_counter, c);
        received == 1 || self.syncs_sent == 0 || age(echo) < age(taken)
    }

    /// What a TPDO not taken was, counted: standard mode, a second one in
    /// the window (duplicated, whatever its values: a late answer to the
    /// SYNC before looks the same); echo mode, a repeat of the one taken for
    /// its SYNC with other values conflicts, anything else (older, an exact
    /// copy) is discarded.
    fn discarded(&mut self, echo: u8, taken: u8, same_values: bool) -> Heard {
        if self.freshness == Some(Freshness::Standard) {
            self.fb.tpdos_duplicated += 1;
            return Heard::Duplicated;
        }
        self.fb.tpdos_discarded += 1;
        if echo == taken && !same_values {
            Heard::Conflicting { sync_counter: echo }
        } else {
            Heard::Discarded
        }
    }

    /// Standard mode: the frame's kernel receive time is before the last
    /// SYNC was sent, so it answers an earlier SYNC (it waited in the
    /// socket). Without a receive time (the UDP bus), never.
    fn received_before_last_sync(&self, received: Option<SystemTime>) -> bool {
        self.freshness == Some(Freshness::Standard)
            && matches!((received, self.last_sync_at), (Some(r), Some(s)) if r < s)
    }

    /// A late TPDO (standard mode), counted and not taken.
    fn late(&mut self) -> Heard {
        self.fb.tpdos_late += 1;
        Heard::Discarded
    }

    /// A heartbeat's NMT state after NMT start: a boot-up is a reset at once;
    /// another state than OPERATIONAL after an OPERATIONAL one is the drive
    /// having left it (a reset of its communication, or its own error
    /// reaction). The first such report is kept ([`Feedback::reset`]).
    fn note_nmt_state(&mut self, s: NmtState) {
        if !self.nmt_started || self.fb.reset.is_some() {
            return;
        }
        match s {
            NmtState::Operational => self.operational_seen = true,
            NmtState::BootUp => self.fb.reset = Some(s),
            NmtState::PreOperational | NmtState::Stopped if self.operational_seen => {
                self.fb.reset = Some(s)
            }
            NmtState::PreOperational | NmtState::Stopped => {}
        }
    }

    /// Reads up to 4 bytes of `o` (expedited upload), little-endian,
    /// zero-padded.
    pub fn sdo_read(&mut self, bus: &mut dyn Transport, o: Object) -> Result<[u8; 4], Cia402Error> {
        bus.send(&frames::sdo_upload(self.settings.node, o))?;
        match self.sdo_response(bus, o)? {
            SdoResponse::Uploaded { data, len, .. } => {
                let mut out = [0u8; 4];
                out[..usize::from(len)].copy_from_slice(&data[..usize::from(len)]);
                Ok(out)
            }
            _ => Err(Cia402Error::InvalidValue {
                field: "SDO upload response",
                raw: 0,
            }),
        }
    }

    fn sdo_read_u32(&mut self, bus: &mut dyn Transport, o: Object) -> Result<u32, Cia402Error> {
        self.sdo_read(bus, o).map(u32::from_le_bytes)
    }

    /// Writes 1 to 4 bytes to `o` (expedited download) and waits for the
    /// confirmation.
    pub fn sdo_write(
        &mut self,
        bus: &mut dyn Transport,
        o: Object,
        value: &[u8],
    ) -> Result<(), Cia402Error> {
        bus.send(&frames::sdo_download(self.settings.node, o, value)?)?;
        match self.sdo_response(bus, o)? {
            SdoResponse::Downloaded { .. } => Ok(()),
            _ => Err(Cia402Error::InvalidValue {
                field: "SDO download response",
                raw: 0,
            }),
        }
    }

    /// Waits for the SDO response to `o`, absorbing other frames meanwhile.
    fn sdo_response(
        &mut self,
        bus: &mut dyn Transport,
        o: Object,
    ) -> Result<SdoResponse, Cia402Error> {
        let start = Instant::now();
        let tx = self.settings.node.sdo_tx();
        loop {
            let left = self
                .settings
                .response_timeout
                .checked_sub(start.elapsed())
                .ok_or(Cia402Error::Timeout {
                    what: "an SDO response",
                    state: self.fb.state,
                })?;
            let Some(f) = bus.recv(left)? else { continue };
            if f.id != tx || !f.is_standard_data() {
                self.absorb(&f);
                continue;
            }
            let r = frames::decode_sdo_response(f.payload())?;
            let (index, subindex) = match r {
                SdoResponse::Downloaded { index, subindex }
                | SdoResponse::Uploaded {
                    index, subindex, ..
                }
                | SdoResponse::Aborted {
                    index, subindex, ..
                } => (index, subindex),
            };
            if (index, subindex) != (o.index, o.subindex) {
                continue; // a late answer to an earlier request
            }
            if let SdoResponse::Aborted { code, .. } = r {
                return Err(Cia402Error::SdoAbort {
                    object: o.name,
                    index,
                    subindex,
                    code,
                });
            }
            return Ok(r);
        }
    }

    /// Leaves the drive safe: controlword shutdown at zero torque (SYNC
    /// stepped until it leaves OperationEnabled), its heartbeat consumer
    /// switched off (0x1016:01 = 0, so the master may go silent), NMT
    /// pre-operational (PDOs stop).
    pub fn shut_down(
        &mut self,
        bus: &mut dyn Transport,
        step: Duration,
    ) -> Result<(), Cia402Error> {
        let disabled = self.drive_towards(bus, step, Goal::Disabled, "ReadyToSwitchOn", |s| {
            s != DriveState::OperationEnabled
        });
        self.sdo_write(bus, od::CONSUMER_HEARTBEAT, &0u32.to_le_bytes())?;
        bus.send(&frames::nmt(
            NmtCommand::EnterPreOperational,
            self.settings.node.get(),
        ))?;
        disabled
    }
}

/// The SYNC counter after `counter`: 1, 2, ..., [`od::SYNC_COUNTER_OVERFLOW`],
/// 1, ... (CiA 301: a SYNC counter is never 0).
fn next_sync_counter(counter: u8) -> u8 {
    counter % od::SYNC_COUNTER_OVERFLOW + 1
}

/// How many SYNCs before the last one sent (counter `last`) the SYNC with
/// counter `echo` went out: 0 for `last` itself, up to
/// [`od::SYNC_COUNTER_OVERFLOW`] - 1 (older ones alias). An echo outside
/// 1..=overflow (0: a SYNC without a counter, not this master's) counts as
/// the oldest possible.
fn syncs_ago(last: u8, echo: u8) -> u8 {
    let n = od::SYNC_COUNTER_OVERFLOW;
    if echo == 0 || echo > n {
        return n;
    }
    // Both in 1..=n: the difference modulo n.
    ((u16::from(last) + u16::from(n) - u16::from(echo)) % u16::from(n)) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn syncs_ago_counts_back_through_the_wrap() {
        assert_eq!(syncs_ago(5, 5), 0);
        assert_eq!(syncs_ago(5, 4), 1);
        assert_eq!(syncs_ago(2, 239), 3);
        assert_eq!(syncs_ago(1, 240), 1);
        assert_eq!(syncs_ago(5, 6), od::SYNC_COUNTER_OVERFLOW - 1);
        assert_eq!(syncs_ago(5, 0), od::SYNC_COUNTER_OVERFLOW);
        assert_eq!(syncs_ago(5, 241), od::SYNC_COUNTER_OVERFLOW);
    }

    #[test]
    fn a_drive_heartbeat_of_200_ms_is_watched_with_a_producer_of_100_ms() {
        let s = MasterSettings::new(CanopenNode::new(1).unwrap())
            .with_drive_heartbeat_timeout(Duration::from_millis(200));
        assert_eq!(s.drive_producer_ms, 100);
        assert_eq!(producer_for(Duration::from_millis(1)), 1);
        assert!(s.validate().is_ok());
    }

    #[test]
    fn sync_counter_runs_1_to_the_overflow_value_then_wraps() {
        let mut c = 0;
        let mut seen = Vec::new();
        for _ in 0..2 * usize::from(od::SYNC_COUNTER_OVERFLOW) {
            c = next_sync_counter(c);
            seen.push(c);
        }
        let one_round: Vec<u8> = (1..=od::SYNC_COUNTER_OVERFLOW).collect();
        assert_eq!(seen[..one_round.len()], one_round[..]);
        assert_eq!(seen[one_round.len()..], one_round[..]);
    }
}
