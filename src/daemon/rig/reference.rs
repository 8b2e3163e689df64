//! The rig's one reference run: both axes (or one) referenced with the
//! supervisor and the poller paused, the soft limits and history reset.

use super::{driver_error, ActivityGuard, Rig};
use crate::daemon::protocol::{Axes, ErrorCode, PairUm, ProtoError};
use crate::daemon::state::{Activity, AxisId, Input};
use crate::driver::Axis;
use std::sync::Arc;
use std::time::Duration;

impl Rig {
    /// References the selected axes (the stage moves to its reference).
    pub async fn reference(
        self: &Arc<Self>,
        axes: Axes,
    ) -> Result<PairUm<Option<f64>>, ProtoError> {
        let stage = self.stage()?;
        let gen = self.stop_generation();
        let _queue = self.motion.lock().await;
        // The play is unknown again after a reference run.
        self.comp.reset_history();
        // A reference run supersedes the moves watched so far (the core
        // drops their watches); a sample in flight finishes before the run
        // starts.
        let t = self.clock.now_s();
        self.core().begin_reference(t)?;
        let _guard = ActivityGuard {
            rig: self,
            activity: Activity::Referencing,
        };
        drop(self.sampling.lock().await);
        if self.stop_generation() != gen {
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came before the reference run started; it was not sent",
            ));
        }
        let run = |axis: &Axis, on: bool| {
            let axis = axis.clone();
            async move {
                if on {
                    axis.reference().await.map(Some)
                } else {
                    Ok(None)
                }
            }
        };
        // A stop or fault during the run halts it (its `HLT` or `#24`); one
        // that came while `SVO`/`FRF` were being sent may have been
        // overtaken by them (the halt goes ahead of the line's queue), so
        // once the generation moved the axes are halted again every
        // supervisor period until the run gives up.
        // The watch runs beside the run (not between its polls: a run
        // suspended inside an exchange holds its controller's lock, which
        // the halt's confirmation needs) and ends with it.
        let period = Duration::from_millis(self.cfg.safety.supervise_interval_ms);
        let (done_tx, mut done_rx) = tokio::sync::oneshot::channel::<()>();
        let runs = async {
            let r = tokio::join!(run(&stage.x, axes.x()), run(&stage.y, axes.y()));
            let _ = done_tx.send(());
            r
        };
        let watch = async {
            loop {
                tokio::select! {
                    _ = &mut done_rx => return,
                    () = tokio::time::sleep(period) => {}
                }
                if self.stop_generation() != gen {
                    self.halt_all().await;
                }
            }
        };
        let ((x, y), ()) = tokio::join!(runs, watch);
        // The counts changed meaning: the deviation check ties afresh, and
        // the vision tie of the last reference no longer applies (the
        // caller ties again after a successful run).
        self.core().retie();
        self.store_tie(Err(
            "a reference run changed the controllers' zero since the last tie; a successful reference run ties again".to_owned(),
        ))
        .await;
        if self.stop_generation() != gen {
            // Halted once more: an `FRF` written after the stop's `#24` or
            // `HLT` runs while its `ERR?` reports the stop (10), so the run
            // can end in an error with the axis still referencing.
            self.halt_all().await;
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came during the reference run; it was halted",
            ));
        }
        let x = x.map_err(driver_error)?;
        let y = y.map_err(driver_error)?;
        self.core().reference_done([x, y]);
        for (a, v) in [(AxisId::X, x), (AxisId::Y, y)] {
            if v.is_some() {
                self.apply(Input::Referenced(a));
            }
        }
        Ok(PairUm::of([x, y]))
    }
}
