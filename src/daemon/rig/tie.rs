//! The rig's vision tie as the rig uses it (`daemon::vision_tie`): the
//! frame that maps a decoded position to stage coordinates (the tie, else
//! the active table's frame), positions through it, and the tie's file
//! (read at start, written when a tie is measured or dropped, on blocking
//! threads).

use super::{lock, Rig};
use crate::comp::VisionFrame;
use crate::daemon::protocol::{VisionPosition, VisionTieStatus};
use crate::daemon::state::AxisId;
use crate::daemon::vision::Measurement;
use crate::daemon::vision_tie::{self, StoredTie, SWITCHED_OFF};
use crate::model::XyUm;
use std::sync::Arc;

/// The vision → stage frame in force and where it comes from.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInForce {
    /// The frame.
    pub frame: VisionFrame,
    /// `"tie after reference, <utc>"` or `"table NAME"`.
    pub source: String,
}

impl Rig {
    /// Whether both axes are referenced.
    pub fn referenced_both(&self) -> bool {
        let c = self.core();
        c.state().referenced(AxisId::X) && c.state().referenced(AxisId::Y)
    }

    /// The frame that maps vision to stage coordinates: the rig's tie
    /// while both axes are referenced (it belongs to their reference),
    /// else the active table's frame (fitted by the characterization that
    /// built it). `Err`: why there is none, in words, for `position` and
    /// `status`.
    pub fn vision_frame(&self) -> Result<FrameInForce, String> {
        let (tie, why) = {
            let t = lock(&self.tie);
            (t.tie().cloned(), t.untied_why().map(str::to_owned))
        };
        let unreferenced: Vec<&str> = {
            let c = self.core();
            [AxisId::X, AxisId::Y]
                .into_iter()
                .filter(|a| !c.state().referenced(*a))
                .map(AxisId::name)
                .collect()
        };
        let why = match (tie, unreferenced.is_empty()) {
            (Some(t), true) => {
                return Ok(FrameInForce {
                    frame: t.frame,
                    source: format!("tie after {}, {}", t.after, t.taken_utc),
                })
            }
            (Some(_), false) => format!(
                "axis {} is not referenced, and the tie belongs to the reference run (reference ties it again)",
                unreferenced.join(" and ")
            ),
            (None, _) => why.unwrap_or_default(),
        };
        if let Some(a) = self.comp.active() {
            if let Some(frame) = a.frame {
                return Ok(FrameInForce {
                    frame,
                    source: format!("table {}", a.name),
                });
            }
        }
        Err(why)
    }

    /// A decoded measurement as `position` and the position
    /// events: its pattern coordinates and, through the frame in force,
    /// `stage_x_um`/`stage_y_um` (stage µm, the controllers' axes and
    /// signs) with `frame` naming it; without a frame `untied` says why and
    /// what that switches off, and there are no stage coordinates.
    pub fn vision_position(&self, m: &Measurement) -> VisionPosition {
        let mut j = VisionPosition {
            measurement: m.to_reply(),
            stage_x_um: None,
            stage_y_um: None,
            frame: None,
            untied: None,
            age_s: None,
        };
        match self.vision_frame() {
            Ok(f) => {
                let s = f.frame.to_stage(XyUm {
                    x_um: m.x_um,
                    y_um: m.y_um,
                });
                j.stage_x_um = Some(s.x_um);
                j.stage_y_um = Some(s.y_um);
                j.frame = Some(f.source);
            }
            Err(why) => {
                j.untied = Some(format!(
                    "vision is not tied to the stage: {why}; {SWITCHED_OFF}"
                ));
            }
        }
        j
    }

    /// The tie's state for `status` (`vision_tie`).
    pub fn tie_status(&self) -> VisionTieStatus {
        if self.vision.is_none() {
            return VisionTieStatus {
                tied: false,
                why: Some("no camera is configured (camera.source)".to_owned()),
                ..VisionTieStatus::default()
            };
        }
        let mut j = lock(&self.tie).to_reply();
        match self.vision_frame() {
            Ok(f) => j.frame_in_force = Some(f.source),
            Err(why) if j.tied => {
                // Tied, but not usable now (an axis lost its reference).
                j.in_force = Some(false);
                j.why = Some(why);
                j.switched_off = Some(SWITCHED_OFF.to_owned());
            }
            Err(_) => {}
        }
        j
    }

    /// Reads the stored tie of the data directory at start (a blocking
    /// thread) and restores it if it was measured with this set-up.
    pub async fn restore_tie(self: Arc<Self>) {
        if self.vision.is_none() {
            return;
        }
        let dir = self.cfg.daemon.data_dir.clone();
        let read = tokio::task::spawn_blocking(move || vision_tie::read_file(&dir))
            .await
            .unwrap_or_else(|e| Err(e.to_string()));
        let mut t = lock(&self.tie);
        t.restore(read, &self.cfg);
        match (t.tie(), t.untied_why()) {
            (Some(s), _) => tracing::info!(
                "vision tie restored from the data directory (taken {}); the first tie at rest confirms it",
                s.taken_utc
            ),
            (None, Some(w)) => tracing::info!("vision untied: {w}"),
            _ => {}
        }
    }

    /// Sets the tie (`Ok`) or drops it for a reason (`Err`), and stores
    /// it (or removes the stored one) in the data directory. A failed write
    /// is logged and returned in words: the tie is in force until the
    /// daemon stops, it only does not survive a restart.
    pub async fn store_tie(&self, tie: Result<StoredTie, String>) -> Option<String> {
        let file = tie.as_ref().ok().cloned();
        match tie {
            Ok(t) => lock(&self.tie).set(t),
            Err(why) => lock(&self.tie).drop_with(why),
        }
        let dir = self.cfg.daemon.data_dir.clone();
        let r = tokio::task::spawn_blocking(move || vision_tie::write_file(&dir, file.as_ref()))
            .await
            .map_err(|e| e.to_string())
            .and_then(|r| r.map_err(|e| e.to_string()));
        r.err().map(|e| {
            let w = format!(
                "the vision tie could not be stored in the data directory ({e}); it holds until microposd stops"
            );
            tracing::warn!("{w}");
            w
        })
    }

    /// The deviation check tied at rest (`tied_um`, controller − rotated
    /// vision): a restored tie is confirmed or dropped
    /// ([`vision_tie::VisionTie::confirm`], at the controllers' last polled
    /// position, at rest); a dropped one's file goes too.
    pub(super) fn confirm_tie(self: &Arc<Self>, tied_um: [f64; 2]) {
        let (_, Some(x), Some(y)) = self.reported_um() else {
            return;
        };
        let Some(why) = lock(&self.tie).confirm(tied_um, [x, y]) else {
            return;
        };
        tracing::warn!("vision untied: {why}");
        let rig = self.clone();
        tokio::spawn(async move {
            rig.store_tie(Err(why)).await;
        });
    }
}
