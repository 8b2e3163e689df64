//! `GET /metrics`, the scrape: copies the values that live elsewhere (the
//! rig's positions, the vision pipeline's counters, drift, the job's
//! progress) into the registry of [`Metrics`] (`daemon::metrics`, owned by
//! the rig) and encodes it. Here, in the web front door that serves it, so
//! the rig's counters never depend on the daemon they are part of.

use crate::daemon::metrics::{AxisLabel, FloatGauge, Metrics, PositionLabel, RATE_WINDOW_S};
use crate::daemon::Daemon;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use std::sync::atomic::Ordering;

impl Metrics {
    /// Copies the values that live elsewhere into the registry and encodes
    /// it (OpenMetrics text, `# EOF` last).
    pub fn render(&self, daemon: &Daemon) -> Result<String, std::fmt::Error> {
        self.sync(daemon);
        let mut out = String::new();
        prometheus_client::encoding::text::encode(&mut out, &self.registry)?;
        Ok(out)
    }

    fn sync(&self, daemon: &Daemon) {
        let rig = &daemon.rig;
        let now_s = rig.clock.now_s();
        let set_axes = |fam: &Family<PositionLabel, FloatGauge>, source, x: Option<f64>, y| {
            for (axis, v) in [("x", x), ("y", y)] {
                if let Some(v) = v.filter(|v: &f64| v.is_finite()) {
                    fam.get_or_create(&PositionLabel { source, axis }).set(v);
                }
            }
        };
        let [cx, cy] = rig.commanded_um();
        set_axes(&self.position_um, "commanded", cx, cy);
        let (_, px, py) = rig.reported_um();
        set_axes(&self.position_um, "controller", px, py);
        if let Some(v) = &rig.vision {
            let s = &v.stats;
            catch_up(&self.frames, s.frames.load(Ordering::Relaxed));
            let decoded = s.decoded.load(Ordering::Relaxed);
            catch_up(&self.frames_decoded, decoded);
            catch_up(&self.decode_failures, s.failed.load(Ordering::Relaxed));
            if let Ok(mut last) = self.rate_sample.lock() {
                match *last {
                    Some((t0, n0)) if now_s - t0 >= RATE_WINDOW_S => {
                        let rate = decoded.saturating_sub(n0) as f64 / (now_s - t0);
                        self.decode_rate_hz.set(rate);
                        *last = Some((now_s, decoded));
                    }
                    Some(_) => {}
                    None => *last = Some((now_s, decoded)),
                }
            }
            let latest = *v.latest.borrow();
            if let Some(m) = latest {
                self.decode_quality_bits.set(m.quality);
                // Through the frame in force (the rig's tie, else the
                // active table's); without one a decoded position is no
                // stage position, and the series are absent.
                let frame = rig.vision_frame().ok().map(|f| f.frame);
                let s = frame.map(|f| {
                    f.to_stage(crate::model::XyUm {
                        x_um: m.x_um,
                        y_um: m.y_um,
                    })
                });
                match s {
                    Some(s) => set_axes(&self.position_um, "vision", Some(s.x_um), Some(s.y_um)),
                    None => {
                        for axis in ["x", "y"] {
                            self.position_um.remove(&PositionLabel {
                                source: "vision",
                                axis,
                            });
                        }
                    }
                }
                let fresh = now_s - m.t_s <= rig.cfg.camera.max_age_s;
                if let (true, Some(s), Some(px), Some(py)) = (fresh, s, px, py) {
                    for (axis, r) in [("x", s.x_um - px), ("y", s.y_um - py)] {
                        self.residual_um.get_or_create(&AxisLabel { axis }).set(r);
                    }
                } else if s.is_none() {
                    self.residual_um.clear();
                }
            }
        }
        let drift = rig.drift.to_json(now_s);
        if let Some(c) = drift["correction_um"].as_array() {
            for (axis, v) in ["x", "y"].into_iter().zip(c) {
                if let Some(v) = v.as_f64() {
                    self.drift_um.get_or_create(&AxisLabel { axis }).set(v);
                }
            }
        }
        let state = rig.status();
        self.faulted
            .set(i64::from(state.rig.fault_latched.is_some()));
        let job = daemon.jobs.status();
        self.job_running.set(i64::from(daemon.jobs.is_running()));
        let done = job.as_ref().map_or(0, |j| j.done);
        let total = job.as_ref().map_or(0, |j| j.total);
        self.job_points_done.set(clamp_i64(done));
        self.job_points_total.set(clamp_i64(total));
        self.job_progress_ratio.set(if total > 0 {
            done as f64 / total as f64
        } else {
            0.0
        });
        self.job_eta_seconds.set(
            job.and_then(|j| j.eta_s)
                .filter(|v| v.is_finite())
                .unwrap_or(0.0),
        );
    }
}

fn clamp_i64(v: u64) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// Raises a counter to `total` (the source's own monotonic count).
fn catch_up(c: &Counter, total: u64) {
    let have = c.get();
    if total > have {
        c.inc_by(total - have);
    }
}
