//! The text and JSON reports of a [`Diagnosis`] (`micropos diagnose`,
//! `--json`).
//!
//! Why a file of its own: presentation only; nothing here computes.

use std::fmt::Write as _;

use super::Diagnosis;

impl Diagnosis {
    /// The human-readable report.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} points, {} held-out folds (whole cycles); base fit identified {} parameters of the model's cyclic tables",
            self.points,
            self.folds,
            self.base_free_params.len()
        );
        let _ = writeln!(
            out,
            "model as given:           rms x {:.4} µm, y {:.4} µm",
            self.model_rms_um.x, self.model_rms_um.y
        );
        let _ = writeln!(
            out,
            "after base fit, held out: rms x {:.4} µm, y {:.4} µm",
            self.baseline_rms_um.x, self.baseline_rms_um.y
        );
        if self.findings.is_empty() {
            let _ = writeln!(
                out,
                "no significant structure in the residuals (held-out z ≥ {}, gain ≥ {} %): the model explains the log to its noise",
                self.options.z_threshold, self.options.min_gain_pct
            );
        }
        for (i, f) in self.findings.iter().enumerate() {
            let _ = writeln!(
                out,
                "\nfinding {}: {} ({} error, variable {})",
                i + 1,
                f.kind,
                f.component,
                f.variable.as_deref().unwrap_or(f.axis.as_str())
            );
            let _ = writeln!(out, "  {}", f.explanation);
            let _ = writeln!(out, "  likely cause: {}", f.cause);
            for (k, v) in &f.params {
                match f.uncertainty.get(k) {
                    Some(u) => {
                        let _ = writeln!(out, "  {k:<22} {v:>12.4} ± {u:.4}");
                    }
                    None => {
                        let _ = writeln!(out, "  {k:<22} {v:>12.4}");
                    }
                }
            }
            let _ = writeln!(
                out,
                "  held-out rms {}: {:.4} → {:.4} µm ({:.1} % better, z = {:.1}); {}",
                f.component,
                f.heldout_rms_before_um,
                f.heldout_rms_after_um,
                f.gain_pct,
                f.significance,
                if f.in_extended_model {
                    format!("model term `{}`", f.term)
                } else {
                    "NOT in the extended model (no model input for this column)".to_string()
                }
            );
        }
        let gx = pct(self.baseline_rms_um.x, self.extended_rms_um.x);
        let gy = pct(self.baseline_rms_um.y, self.extended_rms_um.y);
        let _ = writeln!(
            out,
            "\nextended model, held out: rms x {:.4} µm ({gx:+.1} %), y {:.4} µm ({gy:+.1} %); in-sample x {:.4}, y {:.4} µm",
            self.extended_rms_um.x,
            self.extended_rms_um.y,
            self.extended_fit_rms_um.x,
            self.extended_fit_rms_um.y
        );
        if let Some(w) = &self.with_unmodelled_rms_um {
            let _ = writeln!(
                out,
                "with the log-column findings the model cannot carry, held out: rms x {:.4} µm, y {:.4} µm",
                w.x, w.y
            );
        }
        out
    }

    /// The JSON report (`--json`).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "points": self.points,
            "folds": self.folds,
            "model_rms_um": self.model_rms_um,
            "baseline_rms_um": self.baseline_rms_um,
            "findings": self.findings,
            "extended_rms_um": self.extended_rms_um,
            "extended_fit_rms_um": self.extended_fit_rms_um,
            "with_unmodelled_rms_um": self.with_unmodelled_rms_um,
            "gain_pct": {
                "x": pct(self.baseline_rms_um.x, self.extended_rms_um.x),
                "y": pct(self.baseline_rms_um.y, self.extended_rms_um.y),
            },
            "base_free_params": self.base_free_params,
            "options": self.options,
        })
    }
}

fn pct(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        100.0 * (1.0 - after / before)
    } else {
        0.0
    }
}
