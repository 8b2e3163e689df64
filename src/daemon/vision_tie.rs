//! The rig's vision tie: the rigid frame from the camera's pattern
//! coordinates to the controllers' stage coordinates, measured right after
//! a reference run (`daemon::jobs::tie::tie_rig`, the characterization's
//! own tie procedure on two short lines through where the reference left
//! the stage) and kept in the data directory ([`TIE_FILE`]) across
//! restarts.
//!
//! Why the daemon keeps one of its own: a decoded position is in pattern
//! µm, with the pattern's own origin and orientation; without a frame it is
//! no stage position at all (on the simulated rig, x −4498 µm against the
//! controller's 7500). Before this, only an active table carried a frame,
//! so on a rig without one `position` printed rotated pattern coordinates
//! as `stage_x_um` and the vision-vs-controller deviation check
//! (`daemon::deviation`) never ran, while `status` said it was armed.
//!
//! What a tie belongs to: the reference run it followed (the controllers'
//! zero) and the camera set-up (source, period, code depth, mirror) and
//! controller ports it was measured with. So it is dropped when a reference
//! run begins (the run's own tie replaces it), it applies only while both
//! axes are referenced, and a stored one is not restored under another
//! configuration. A restored tie is also checked against the rig: the
//! deviation check's first tie at rest (controller − rotated vision, see
//! `daemon::deviation`) must agree with the stored translation within
//! [`RESTORE_AGREE_UM`], else the controllers' zero or the camera moved
//! since (a re-reference by another program, a remounted camera) and the
//! tie is dropped with that reason. The states and their reasons are plain
//! text for `status` and `position` ([`VisionTie::to_json`]).
//!
//! Sans-IO except [`read_file`] and [`write_file`], which the rig runs on
//! blocking threads.

use crate::comp::{FrameReport, VisionFrame};
use crate::daemon::config::DaemonConfig;
use crate::daemon::protocol::{to_value, PerAxis, VisionTieStatus};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

/// The tie's file in the data directory (`tables list` shows only `.toml`
/// files, so it is not taken for a table).
pub const TIE_FILE: &str = "vision-tie.json";

/// Largest disagreement between a restored tie's translation and the
/// rig's own at rest, after the linear stage errors the tie measured
/// ([`VisionTie::confirm`]), before the restored tie is dropped, µm per
/// axis. Why 20 µm: above the stage errors left (cyclic error, backlash,
/// thermal drift: on the simulated paper stage about 5 µm across the
/// travel), below what a different zero or a remounted camera gives
/// (arbitrary, usually millimetres).
pub const RESTORE_AGREE_UM: f64 = 20.0;

/// File format version of [`StoredTie`].
const VERSION: u32 = 1;

/// What a tie was measured with: a stored tie taken under another set-up
/// is not restored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TieSetup {
    /// `camera.source`.
    pub camera_source: String,
    /// `camera.period_um`.
    pub period_um: f64,
    /// `camera.bits`.
    pub bits: u32,
    /// `camera.mirrored`.
    pub mirrored: bool,
    /// The X controller's port.
    pub x_port: String,
    /// The Y controller's port.
    pub y_port: String,
}

impl TieSetup {
    /// The set-up of `cfg`.
    pub fn of(cfg: &DaemonConfig) -> Self {
        Self {
            camera_source: cfg.camera.source.clone(),
            period_um: cfg.camera.period_um,
            bits: cfg.camera.bits,
            mirrored: cfg.camera.mirrored,
            x_port: cfg.driver.x.port.display().to_string(),
            y_port: cfg.driver.y.port.display().to_string(),
        }
    }

    /// The keys where `self` (stored) and `now` differ, as
    /// `key (stored → now)` texts.
    fn differences(&self, now: &TieSetup) -> Vec<String> {
        let mut d = Vec::new();
        let mut cmp = |k: &str, a: String, b: String| {
            if a != b {
                d.push(format!("{k} ({a} → {b})"));
            }
        };
        cmp(
            "camera.source",
            self.camera_source.clone(),
            now.camera_source.clone(),
        );
        cmp(
            "camera.period_um",
            self.period_um.to_string(),
            now.period_um.to_string(),
        );
        cmp("camera.bits", self.bits.to_string(), now.bits.to_string());
        cmp(
            "camera.mirrored",
            self.mirrored.to_string(),
            now.mirrored.to_string(),
        );
        cmp("driver.x.port", self.x_port.clone(), now.x_port.clone());
        cmp("driver.y.port", self.y_port.clone(), now.y_port.clone());
        d
    }
}

/// A tie as stored in [`TIE_FILE`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredTie {
    /// File format version.
    pub version: u32,
    /// Vision (pattern µm) → stage (controller µm): `stage = R·vision + t`.
    pub frame: VisionFrame,
    /// When it was measured, RFC 3339 UTC.
    pub taken_utc: String,
    /// What it followed (`"reference"`).
    pub after: String,
    /// Where the tie's lines crossed (its anchor), stage µm `[x, y]`.
    pub anchor_um: [f64; 2],
    /// Lead error plus expansion seen along the X line, ppm.
    pub x_scale_ppm: f64,
    /// Same along the Y line, ppm.
    pub y_scale_ppm: f64,
    /// Squareness seen between the lines, µrad (model sign).
    pub squareness_urad: f64,
    /// RMS of `command − stage(vision)` over the lines `[x, y]`, µm.
    pub rms_error_um: [f64; 2],
    /// The set-up it was measured with.
    pub setup: TieSetup,
}

impl StoredTie {
    /// A tie just measured under `cfg`.
    pub fn new(
        cfg: &DaemonConfig,
        frame: VisionFrame,
        report: &FrameReport,
        anchor_um: [f64; 2],
        taken_utc: String,
    ) -> Self {
        Self {
            version: VERSION,
            frame,
            taken_utc,
            after: "reference".to_owned(),
            anchor_um,
            x_scale_ppm: report.x_scale_ppm,
            y_scale_ppm: report.y_scale_ppm,
            squareness_urad: report.squareness_urad,
            rms_error_um: report.rms_error_um,
            setup: TieSetup::of(cfg),
        }
    }

    /// Parses a stored tie; `Err` says why it cannot be used.
    pub fn parse(bytes: &[u8]) -> Result<Self, String> {
        let t: StoredTie = serde_json::from_slice(bytes).map_err(|e| e.to_string())?;
        if t.version != VERSION {
            return Err(format!(
                "format version {} (this daemon reads {VERSION})",
                t.version
            ));
        }
        t.frame.validate().map_err(|e| e.to_string())?;
        Ok(t)
    }
}

/// The tie's state.
#[derive(Debug, Clone, PartialEq)]
enum State {
    /// No tie; why, in words.
    Untied(String),
    /// A tie in force.
    Tied {
        tie: Box<StoredTie>,
        restored: Restored,
    },
}

/// Where a tie in force came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Restored {
    /// Measured by this daemon.
    No,
    /// Read from the file at start, not yet confirmed by the rig.
    Unconfirmed,
    /// Read from the file at start and confirmed at rest.
    Confirmed,
}

/// The rig's vision tie (a component of the rig, behind its mutex).
#[derive(Debug, Clone, PartialEq)]
pub struct VisionTie {
    state: State,
}

impl Default for VisionTie {
    fn default() -> Self {
        Self {
            state: State::Untied(
                "no reference run has tied it since microposd started (reference ties it)"
                    .to_owned(),
            ),
        }
    }
}

impl VisionTie {
    /// The tie in force, if any.
    pub fn tie(&self) -> Option<&StoredTie> {
        match &self.state {
            State::Tied { tie, .. } => Some(tie),
            State::Untied(_) => None,
        }
    }

    /// Why there is no tie (`None`: tied).
    pub fn untied_why(&self) -> Option<&str> {
        match &self.state {
            State::Untied(w) => Some(w),
            State::Tied { .. } => None,
        }
    }

    /// A tie just measured.
    pub fn set(&mut self, tie: StoredTie) {
        self.state = State::Tied {
            tie: Box::new(tie),
            restored: Restored::No,
        };
    }

    /// Drops the tie (if any) for the reason `why`.
    pub fn drop_with(&mut self, why: impl Into<String>) {
        self.state = State::Untied(why.into());
    }

    /// The stored tie read at start (`read`: the file's bytes, `None`: no
    /// file) under the configuration `cfg`: restored (unconfirmed) when it
    /// parses and was measured under the same set-up, else untied with the
    /// reason.
    pub fn restore(&mut self, read: Result<Option<Vec<u8>>, String>, cfg: &DaemonConfig) {
        let bytes = match read {
            Ok(Some(b)) => b,
            Ok(None) => return,
            Err(e) => {
                self.drop_with(format!(
                    "the stored tie ({TIE_FILE} in the data directory) could not be read: {e}; reference ties it again"
                ));
                return;
            }
        };
        let tie = match StoredTie::parse(&bytes) {
            Ok(t) => t,
            Err(e) => {
                self.drop_with(format!(
                    "the stored tie ({TIE_FILE}) is not usable: {e}; reference ties it again"
                ));
                return;
            }
        };
        let diff = tie.setup.differences(&TieSetup::of(cfg));
        if !diff.is_empty() {
            self.drop_with(format!(
                "the stored tie (taken {}) was measured with another set-up: {}; reference ties it again",
                tie.taken_utc,
                diff.join(", ")
            ));
            return;
        }
        self.state = State::Tied {
            tie: Box::new(tie),
            restored: Restored::Unconfirmed,
        };
    }

    /// The deviation check tied its translation at rest (`tied_um`:
    /// controller − rotated vision, µm, with this tie's orientation) with
    /// the controllers at `at_um`: a restored tie is confirmed when its
    /// translation agrees within [`RESTORE_AGREE_UM`] after the stage's
    /// linear errors the tie measured are taken out, and dropped
    /// otherwise. Returns the reason when it was dropped.
    ///
    /// Why the linear errors: the tie's origin is where vision and
    /// controller agree on its X line; elsewhere they differ by the stage's
    /// errors, mostly squareness and lead (on the simulated paper stage
    /// 5.3 mrad: 24 µm at 4.5 mm from the tie). With `s` the squareness
    /// (rad) and `εx`, `εy` the scales the tie saw, from the anchor `a`,
    /// vision − controller ≈ `[εx·(x − ax) + s·(y − ay), εy·(y − ay)]`, and
    /// `tied_um − t` is its negative.
    pub fn confirm(&mut self, tied_um: [f64; 2], at_um: [f64; 2]) -> Option<String> {
        let State::Tied {
            tie,
            restored: Restored::Unconfirmed,
        } = &self.state
        else {
            return None;
        };
        let t = tie.frame.translation_um;
        let (dx, dy) = (at_um[0] - tie.anchor_um[0], at_um[1] - tie.anchor_um[1]);
        let expected = [
            tie.x_scale_ppm * 1e-6 * dx + tie.squareness_urad * 1e-6 * dy,
            tie.y_scale_ppm * 1e-6 * dy,
        ];
        let d = [
            tied_um[0] - t[0] + expected[0],
            tied_um[1] - t[1] + expected[1],
        ];
        if d.iter().all(|v| v.abs() <= RESTORE_AGREE_UM) {
            let tie = tie.clone();
            self.state = State::Tied {
                tie,
                restored: Restored::Confirmed,
            };
            return None;
        }
        let why = format!(
            "the stored tie (taken {}) disagrees with the rig by x {:+.1} µm, y {:+.1} µm at rest at ({:.1}, {:.1}) µm, beyond the stage errors the tie measured (more than {RESTORE_AGREE_UM} µm): the controllers' zero or the camera moved since; reference ties it again",
            tie.taken_utc, d[0], d[1], at_um[0], at_um[1]
        );
        self.drop_with(why.clone());
        Some(why)
    }

    /// For `status`: `tied`, and either the tie (its frame, when, what it
    /// saw, whether a restored tie is confirmed yet) or `why` not and
    /// `switched_off`, what an untied camera cannot do.
    pub fn to_reply(&self) -> VisionTieStatus {
        match &self.state {
            State::Untied(why) => VisionTieStatus {
                tied: false,
                why: Some(why.clone()),
                switched_off: Some(SWITCHED_OFF.to_owned()),
                ..VisionTieStatus::default()
            },
            State::Tied { tie, restored } => VisionTieStatus {
                tied: true,
                after: Some(tie.after.clone()),
                taken_utc: Some(tie.taken_utc.clone()),
                restored: Some(match restored {
                    Restored::No => "no",
                    Restored::Unconfirmed => "from the data directory, not yet confirmed (the deviation check's first tie at rest confirms it)",
                    Restored::Confirmed => "from the data directory, confirmed at rest",
                }.to_owned()),
                rotation_rad: Some(tie.frame.rotation_rad),
                mirrored: Some(tie.frame.mirrored),
                translation_um: Some(PerAxis::of(tie.frame.translation_um)),
                anchor_um: Some(PerAxis::of(tie.anchor_um)),
                squareness_urad: Some(tie.squareness_urad),
                scale_ppm: Some(PerAxis::of([tie.x_scale_ppm, tie.y_scale_ppm])),
                rms_error_um: Some(PerAxis::of(tie.rms_error_um)),
                ..VisionTieStatus::default()
            },
        }
    }

    /// [`to_reply`](Self::to_reply) as JSON.
    pub fn to_json(&self) -> Value {
        to_value(&self.to_reply())
    }
}

/// What an untied camera cannot do, for `status` and `position`.
pub const SWITCHED_OFF: &str = "vision positions are pattern coordinates, not stage positions; \
     the vision-vs-controller deviation check runs only with an active table's frame \
     (or safety.deviation_frame = \"camera\")";

/// Reads the stored tie of `data_dir` (`Ok(None)`: none stored). Blocking.
pub fn read_file(data_dir: &Path) -> Result<Option<Vec<u8>>, String> {
    match crate::nofollow::read(&data_dir.join(TIE_FILE)) {
        Ok(b) => Ok(Some(b)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e.to_string()),
    }
}

/// Stores `tie` in `data_dir` (`None`: removes the file, so a dropped tie
/// is not restored after a restart). Blocking.
pub fn write_file(data_dir: &Path, tie: Option<&StoredTie>) -> std::io::Result<()> {
    let path = data_dir.join(TIE_FILE);
    match tie {
        Some(t) => {
            let text = serde_json::to_vec_pretty(t).map_err(std::io::Error::other)?;
            crate::nofollow::write_atomic(&path, &text)
        }
        None => match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
            _ => Ok(()),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> DaemonConfig {
        let mut c = DaemonConfig::default();
        c.camera.source = "sim:/tmp/rig/camera.sock".to_owned();
        c.driver.x.port = "/tmp/rig/x".into();
        c.driver.y.port = "/tmp/rig/y".into();
        c
    }

    fn tie(c: &DaemonConfig) -> StoredTie {
        StoredTie::new(
            c,
            VisionFrame {
                rotation_rad: -3.13,
                mirrored: false,
                translation_um: [10_000.0, 14_000.0],
            },
            &FrameReport {
                x_scale_ppm: 1.0,
                y_scale_ppm: 2.0,
                squareness_urad: 3.0,
                rms_error_um: [0.1, 0.2],
            },
            [7500.0, 7500.0],
            "2026-01-01T00:00:00Z".to_owned(),
        )
    }

    /// A stored tie comes back under the same set-up, unconfirmed, and is
    /// confirmed by a tie at rest within 20 µm of its translation.
    #[test]
    fn a_stored_tie_is_restored_and_confirmed_at_rest() {
        let c = cfg();
        let bytes = serde_json::to_vec(&tie(&c)).unwrap();
        let mut v = VisionTie::default();
        v.restore(Ok(Some(bytes)), &c);
        assert_eq!(v.tie(), Some(&tie(&c)));
        assert!(v.to_json()["restored"]
            .as_str()
            .unwrap()
            .starts_with("from the data directory, not yet confirmed"));
        assert_eq!(v.confirm([10_003.0, 13_990.0], [7500.0, 7500.0]), None);
        assert_eq!(
            v.to_json()["restored"],
            "from the data directory, confirmed at rest"
        );
        // Confirmed once: a later tie at rest is the check's business.
        assert_eq!(v.confirm([0.0, 0.0], [7500.0, 7500.0]), None);
        assert!(v.tie().is_some());
    }

    /// Far from the tie the stage's squareness and lead errors the tie
    /// measured are expected, not a moved zero: 5.3 mrad over 4.5 mm of y
    /// (24 µm on x) confirms; the same with a 25 µm shift does not.
    #[test]
    fn confirmation_expects_the_stage_errors_the_tie_measured() {
        let c = cfg();
        let mut t = tie(&c);
        t.squareness_urad = 5300.0;
        t.x_scale_ppm = 0.0;
        t.y_scale_ppm = 0.0;
        let bytes = serde_json::to_vec(&t).unwrap();
        // Vision − controller at (2000, 12000): +23.85 µm on x; the
        // judge's tie is its negative plus the translation.
        let at = [2000.0, 12_000.0];
        let mut v = VisionTie::default();
        v.restore(Ok(Some(bytes.clone())), &c);
        assert_eq!(v.confirm([10_000.0 - 23.85, 14_000.0], at), None);
        assert!(v.tie().is_some());
        let mut v = VisionTie::default();
        v.restore(Ok(Some(bytes)), &c);
        assert!(v.confirm([10_000.0 - 48.85, 14_000.0], at).is_some());
    }

    /// A restored tie whose translation the rig does not confirm is
    /// dropped with the disagreement in the reason.
    #[test]
    fn a_restored_tie_the_rig_contradicts_is_dropped() {
        let c = cfg();
        let mut v = VisionTie::default();
        v.restore(Ok(Some(serde_json::to_vec(&tie(&c)).unwrap())), &c);
        let why = v.confirm([10_000.0, 14_025.0], [7500.0, 7500.0]).unwrap();
        assert!(why.contains("y +25.0 µm"), "{why}");
        assert!(v.tie().is_none());
        assert_eq!(v.to_json()["tied"], false);
        assert_eq!(v.to_json()["switched_off"], SWITCHED_OFF);
    }

    /// Another camera or port, a damaged file, another version: untied,
    /// saying which and why; no file: the default reason.
    #[test]
    fn a_stored_tie_of_another_setup_or_a_bad_file_is_not_restored() {
        let c = cfg();
        let bytes = serde_json::to_vec(&tie(&c)).unwrap();
        let mut other = c.clone();
        other.camera.period_um = 4.0;
        other.driver.y.port = "/dev/ttyUSB1".into();
        let mut v = VisionTie::default();
        v.restore(Ok(Some(bytes.clone())), &other);
        let why = v.untied_why().unwrap();
        assert!(why.contains("camera.period_um (9 → 4)"), "{why}");
        assert!(
            why.contains("driver.y.port (/tmp/rig/y → /dev/ttyUSB1)"),
            "{why}"
        );
        let mut v = VisionTie::default();
        v.restore(Ok(Some(b"{".to_vec())), &c);
        assert!(v.untied_why().unwrap().contains("not usable"));
        let mut t = tie(&c);
        t.version = 7;
        let mut v = VisionTie::default();
        v.restore(Ok(Some(serde_json::to_vec(&t).unwrap())), &c);
        assert!(v.untied_why().unwrap().contains("format version 7"));
        let mut v = VisionTie::default();
        v.restore(Ok(None), &c);
        assert_eq!(v, VisionTie::default());
        v.restore(Err("permission denied".to_owned()), &c);
        assert!(v.untied_why().unwrap().contains("permission denied"));
    }

    /// The file round-trips; `None` removes it; a missing file is no tie.
    #[test]
    fn the_file_round_trips_and_is_removed() {
        let d = tempfile::tempdir().unwrap();
        let c = cfg();
        assert_eq!(read_file(d.path()), Ok(None));
        write_file(d.path(), Some(&tie(&c))).unwrap();
        let b = read_file(d.path()).unwrap().unwrap();
        assert_eq!(StoredTie::parse(&b), Ok(tie(&c)));
        write_file(d.path(), None).unwrap();
        write_file(d.path(), None).unwrap();
        assert_eq!(read_file(d.path()), Ok(None));
    }
}
