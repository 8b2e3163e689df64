//! The text and JSON reports of a [`Diagnosis`] (`micropos diagnose`,
//! `--json`).
//!
//! Why a file of its own: presentation only; nothing here computes.

use std::fmt::Write as _;

use super::{ComponentNoise, Diagnosis, RmsXy, MEASURED_AXES_KEY};
use crate::model::Axis;

impl Diagnosis {
    /// The log's ISO 230-2 figures per measured component, the first thing
    /// a metrologist reads: what the log measures before any model.
    fn iso_text(&self) -> String {
        let mut out = String::new();
        for c in &self.noise.components {
            let a = c.component;
            if let Some(iso) = &c.iso230_2 {
                let fig = |f: &super::noise::IsoFigures| {
                    format!(
                        "R {:.4} µm (R↑ {:.4}, R↓ {:.4}), B {:.4} µm (B̄ {:+.4} µm), E {:.4} µm, M {:.4} µm, A {:.4} µm",
                        f.r_um, f.r_up_um, f.r_down_um, f.b_um, f.mean_b_um, f.e_um, f.m_um, f.a_um
                    )
                };
                let _ = writeln!(
                    out,
                    "  {a}: ISO 230-2 ({} cycles, all {} visits{}, as the standard defines the figures and a test report computes them{}): {}",
                    iso.cycles,
                    iso.visits,
                    if c.outliers.is_empty() { "" } else { " including the excluded ones" },
                    match iso.paired_within_um {
                        Some(w) => format!("; a target's forward and backward arrivals stopped up to {w:.1} µm apart and are paired, as the test's own report pairs them: not a test of the standard's form"),
                        None => String::new(),
                    },
                    fig(iso)
                );
                if let Some(w) = &c.iso230_2_without_outliers {
                    let _ = writeln!(
                        out,
                        "  {a}: ISO 230-2 figures without the {} excluded visit(s) ({} visits; each target's x̄ and s from the visits it keeps; not the standard's figures): {}",
                        iso.visits.saturating_sub(w.visits),
                        w.visits,
                        fig(w)
                    );
                }
            }
        }
        if !out.is_empty() {
            out.insert_str(
                0,
                "what the log measures (ISO 230-2, per direction; the standard's deviation = measured − target):\n",
            );
        }
        out
    }

    /// The human-readable report.
    pub fn to_text(&self) -> String {
        let mut out = self.overview_text();
        out.push_str(&self.base_fit_text());
        let _ = writeln!(
            out,
            "model as given:           rms {}",
            self.rms_text(&self.model_rms_um)
        );
        let _ = writeln!(
            out,
            "after base fit, held out: rms {}",
            self.rms_text(&self.baseline_rms_um)
        );
        if let Some(why) = &self.folds_interleaved {
            let _ = writeln!(out, "folds interleaved in time: {why}");
        }
        out.push_str(&self.verdict_text());
        out.push_str(&self.findings_text());
        out.push_str(&self.withdrawn_text());
        let _ = writeln!(
            out,
            "\nextended model, held out: rms {}; in-sample {}",
            Axis::ALL
                .iter()
                .filter(|a| self.is_measured(**a))
                .map(|a| format!(
                    "{a} {:.4} µm ({:+.1} %)",
                    self.extended_rms_um.get(*a),
                    pct(self.baseline_rms_um.get(*a), self.extended_rms_um.get(*a))
                ))
                .collect::<Vec<_>>()
                .join(", "),
            self.rms_text(&self.extended_fit_rms_um)
        );
        if let Some(w) = &self.with_unmodelled_rms_um {
            let _ = writeln!(
                out,
                "with the log-column findings the model cannot carry, held out: rms {}",
                self.rms_text(w)
            );
        }
        out.push_str(&self.map_term_text());
        out.push_str(&self.noise_text());
        out
    }

    /// The report's opening: the map's own reading (grid logs), the
    /// ISO 230-2 figures, and what the log lets the analysis use (points,
    /// folds, measured axes, time).
    fn overview_text(&self) -> String {
        let mut out = String::new();
        // A map's own reading first: what the grid measures, in the
        // stage's frame, before anything read through the stage model.
        if let Some(g) = &self.grid {
            crate::analysis::grid::write_text(&mut out, g);
            let _ = writeln!(
                out,
                "\nthe stage model's reading of the same log{}:",
                match self.frame_turn_urad {
                    Some(t) => format!(" (its readings turned by {t:+.2} µrad first, so that the stage's x axis is the frame's x: the model's squareness is then the stage's)"),
                    None => String::new(),
                }
            );
        }
        out.push_str(&self.iso_text());
        let _ = writeln!(
            out,
            "{} points ({} judged held out), {} held-out folds ({}); measured axes: {}{}",
            self.points,
            self.judged_points,
            self.folds,
            if self.folds_interleaved.is_some() {
                "blocks of 4 consecutive points dealt round, interleaved in time"
            } else if self.whole_cycle_folds {
                "whole cycles"
            } else {
                "contiguous chunks of the log's one cycle"
            },
            self.measured_axes
                .iter()
                .map(|a| a.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            match Axis::ALL.iter().find(|a| !self.is_measured(**a)) {
                Some(a) if self.measured_from == "metadata" => format!(
                    " ({a} not measured, per the log's {MEASURED_AXES_KEY} metadata: nothing fitted or reported on it)"
                ),
                Some(a) => format!(
                    " ({a} not measured: {a}_meas_um is a constant placeholder; nothing fitted or reported on it)"
                ),
                None => String::new(),
            }
        );
        if let Some((a, r)) = self.time_with {
            let _ = writeln!(
                out,
                "time and {a} position move together over this log (r = {r:+.3}; a one-way scan at a steady rate): a drift cannot be told from an error along {a}, so nothing is fitted or searched as a function of time"
            );
        }
        if let Some(why) = &self.time_unusable {
            let _ = writeln!(out, "time: {why}");
        }
        if self.synthetic_time {
            let _ = writeln!(
                out,
                "times: synthetic (the log's {}: record order, one record per second): a rate per hour below is per 3600 records, and no time structure is real time",
                super::TIME_SOURCE_KEY
            );
        }
        out
    }

    /// Step 2's outcome: the parameters fitted, those kept at the
    /// model's value and why, and the parameter corrections.
    fn base_fit_text(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "base fit identified {} parameters of the model (its own structure, this stage's values)",
            self.base_free_params.len()
        );
        // Fixed parameters, grouped by reason.
        let mut reasons: Vec<(&str, Vec<String>)> = Vec::new();
        for p in &self.base_fixed_params {
            match reasons.iter_mut().find(|(r, _)| *r == p.reason) {
                Some((_, v)) => v.push(p.name.clone()),
                None => reasons.push((&p.reason, vec![p.name.clone()])),
            }
        }
        for (reason, names) in reasons {
            let _ = writeln!(
                out,
                "  {} kept at the model's value ({reason}): {}",
                names.len(),
                abbreviate(&names)
            );
        }
        if self.base_fixed_params.iter().any(|p| p.aliased) {
            let _ = writeln!(
                out,
                "  the aliased parameters, at the model's values, contribute {} rms at the log's points: a claim of the model the log can neither confirm nor correct",
                Axis::ALL
                    .iter()
                    .filter(|a| self.is_measured(**a))
                    .map(|a| format!("{a} {:.4} µm", self.aliased_contribution_rms_um.get(*a)))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        for l in self
            .leads
            .iter()
            .filter(|l| l.verdict != super::LeadVerdict::Corrected)
        {
            let _ = writeln!(out, "  screw lead: {}", l.sentence);
        }
        out.push_str(&self.parameters_text());
        out
    }

    /// The sentence when no finding is reported: why, and whether the
    /// model explains the log to its noise all the same.
    fn verdict_text(&self) -> String {
        let mut out = String::new();
        let unexplained: Vec<&ComponentNoise> = self
            .noise
            .components
            .iter()
            .filter(|c| c.unexplained)
            .collect();
        // A map whose separable reading leaves a joint or unexplained
        // error is not explained to its noise, whatever the 1-D search
        // found.
        let map_left = self.grid.as_ref().is_some_and(|g| {
            g.components
                .iter()
                .any(|c| c.non_separable.is_some() || c.unexplained.is_some())
        });
        if self.findings.is_empty() && !self.withdrawn.is_empty() {
            let _ = writeln!(
                out,
                "no finding is reported: {} candidate(s) passed the held-out test (z ≥ {}, gain ≥ {} %) but the log does not determine their numbers (withdrawn, below)",
                self.withdrawn.len(),
                self.options.z_threshold,
                self.options.min_gain_pct
            );
        } else if self.findings.is_empty() && unexplained.is_empty() && map_left {
            let _ = writeln!(
                out,
                "no finding of the stage model passes the held-out test (z ≥ {}, gain ≥ {} %), but the map is NOT explained to its noise: see the grid map's FINDING / UNEXPLAINED lines above",
                self.options.z_threshold, self.options.min_gain_pct
            );
        } else if self.findings.is_empty() && unexplained.is_empty() {
            let _ = writeln!(
                out,
                "no significant structure in the residuals (held-out z ≥ {}, gain ≥ {} %): the model explains the log to its noise",
                self.options.z_threshold, self.options.min_gain_pct
            );
        } else if self.findings.is_empty() {
            let _ = writeln!(
                out,
                "no finding passes the held-out test (z ≥ {}, gain ≥ {} %), but the model does NOT explain the log to its noise: see `unexplained` below",
                self.options.z_threshold, self.options.min_gain_pct
            );
        }
        out
    }

    /// Each finding: its sentence, cause, parameters and held-out test.
    fn findings_text(&self) -> String {
        let mut out = String::new();
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
        out
    }

    /// Whether the log measures axis `a`: the report gives figures for
    /// measured axes only.
    fn is_measured(&self, a: Axis) -> bool {
        self.measured_axes.contains(&a)
    }

    /// RMS figures `r` of the measured axes, for one line of the report.
    fn rms_text(&self, r: &RmsXy) -> String {
        Axis::ALL
            .iter()
            .filter(|a| self.is_measured(**a))
            .map(|a| format!("{a} {:.4} µm", r.get(*a)))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The 2-D map term's section of the text report (grid logs): per
    /// component, whether a `position_map` joined the extended model and
    /// its held-out scores under every fold scheme; empty for other logs.
    fn map_term_text(&self) -> String {
        let Some(m) = &self.map_term else {
            return String::new();
        };
        let mut out = String::new();
        let nodes = m.components.first().map_or([0, 0], |c| c.nodes);
        let _ = writeln!(
            out,
            "\n2-D map term (the extended model's residual at the grid's {} × {} nodes, bilinear between them; a held-out node is predicted from its training neighbours, the model alone predicts zero):",
            nodes[0], nodes[1]
        );
        for c in &m.components {
            let _ = writeln!(out, "  {}: {}", c.component, c.verdict);
            let folds: Vec<String> = c
                .folds
                .iter()
                .map(|f| {
                    format!(
                        "{} {:.4} → {:.4} µm ({} cells)",
                        f.scheme, f.model_um, f.with_map_um, f.cells
                    )
                })
                .collect();
            let _ = writeln!(
                out,
                "    held out: {}; one cell's noise {:.4} µm; layers: {}",
                folds.join(", "),
                c.cell_noise_um,
                c.layers.join(" and ")
            );
        }
        out
    }

    /// The withdrawn candidates' section of the text report: what each
    /// was (kind, component, variable) and why the log does not determine
    /// it; empty when none was withdrawn.
    ///
    /// Why no numbers of its own: a withdrawn candidate's parameters are
    /// the ones the log does not determine, and its held-out gain is not
    /// credited (the extended model does not include it); the reason
    /// quotes the one number that made it fail.
    fn withdrawn_text(&self) -> String {
        if self.withdrawn.is_empty() {
            return String::new();
        }
        let mut out = format!(
            "\nwithdrawn (not determined by this log; not in the extended model, no gain credited): {}\n",
            self.withdrawn.len()
        );
        for w in &self.withdrawn {
            let f = &w.finding;
            let _ = writeln!(
                out,
                "  {} ({} error, variable {}) because {}",
                f.kind,
                f.component,
                f.variable.as_deref().unwrap_or(f.axis.as_str()),
                w.reason
            );
        }
        out
    }

    /// The parameter-corrections section of the text report: the model's
    /// own parameters as the log measured them (not findings), and the
    /// combinations the log cannot separate.
    fn parameters_text(&self) -> String {
        let mut out = String::new();
        let (sig, agree): (Vec<_>, Vec<_>) = self.parameters.iter().partition(|p| p.significant);
        if sig.is_empty() {
            let _ = writeln!(
                out,
                "parameter corrections: none (the {} identified parameters agree with the model within {} σ)",
                agree.len(),
                super::SIGNIFICANT_SIGMAS
            );
        } else {
            let _ = writeln!(
                out,
                "parameter corrections (the model's own terms, this stage's values; not findings): {} of {} identified parameters differ by ≥ {} σ",
                sig.len(),
                self.parameters.len(),
                super::SIGNIFICANT_SIGMAS
            );
            // Corrected screw leads first (they change what every cyclic
            // amplitude means), then the largest departures (in σ).
            let mut sig = sig;
            sig.sort_by(|a, b| {
                let z = |p: &&super::ParamCorrection| {
                    (p.fitted_value - p.model_value).abs() / p.std_error.max(1e-300)
                };
                let lead = |p: &&super::ParamCorrection| p.parameter == super::lead::LEAD_PARAM;
                lead(b).cmp(&lead(a)).then(z(b).total_cmp(&z(a)))
            });
            for p in sig.iter().take(PARAMS_SHOWN) {
                let _ = writeln!(out, "  {}", p.sentence);
            }
            if sig.len() > PARAMS_SHOWN {
                let _ = writeln!(
                    out,
                    "  … {} more in the JSON report (`parameters`)",
                    sig.len() - PARAMS_SHOWN
                );
            }
        }
        for u in &self.unidentifiable {
            let _ = writeln!(out, "  not separable: {}", u.sentence);
        }
        out
    }

    /// The noise section of the text report: repeatability, what is left
    /// unexplained against it, what the sampling cannot resolve.
    fn noise_text(&self) -> String {
        let mut out = String::from("\nnoise from the data:\n");
        for c in &self.noise.components {
            out.push_str(&repeatability_text(c));
            out.push_str(&residual_noise_text(c));
        }
        out.push_str(&self.sampling_text());
        out.push_str(&self.readings_text());
        out
    }

    /// The sampling of each axis, and the periods it aliases.
    fn sampling_text(&self) -> String {
        let mut out = String::new();
        for s in &self.noise.sampling {
            let _ = write!(
                out,
                "  sampling {}: {} positions, {:.1} µm apart over {:.1} µm: periodic errors shorter than {:.1} µm are aliased",
                s.axis, s.positions, s.spacing_um, s.span_um, s.shortest_period_um
            );
            if s.targets < s.positions {
                let _ = write!(
                    out,
                    "; the {} positions are {} targets (positions up to {:.1} µm apart stand for one target: the approaches stopped at different positions)",
                    s.positions, s.targets, s.target_width_um
                );
            }
            if s.positions < super::search::MIN_PROFILE_POSITIONS {
                let _ = write!(
                    out,
                    "; too few positions (< {}) to search periodic or localized errors along {}",
                    super::search::MIN_PROFILE_POSITIONS,
                    s.axis
                );
            }
            out.push('\n');
        }
        out
    }

    /// The structure read from the replicates alone, with no model.
    fn readings_text(&self) -> String {
        let mut out = String::new();
        let readings: Vec<&super::Reading> = self
            .noise
            .components
            .iter()
            .flat_map(|c| &c.readings)
            .collect();
        if !readings.is_empty() {
            out.push_str(
                "\nstructure read from the replicates (no model; z against the repeatability):\n",
            );
            for r in readings {
                let _ = writeln!(
                    out,
                    "  {} ({}, z = {:.1}){}: {}\n    likely cause: {}",
                    r.kind.as_str(),
                    r.component,
                    r.z,
                    match r.model_explains {
                        Some(true) => " — the model carries it (gone from its held-out residual)",
                        Some(false) => " — the model LACKS it (still in its held-out residual)",
                        None => "",
                    },
                    r.sentence,
                    r.cause
                );
                if let Some(t) = &r.term {
                    let _ = writeln!(out, "    as a model term: {}", t.sentence);
                }
            }
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
            "parameters": self.parameters,
            "leads": self.leads,
            "unidentifiable": self.unidentifiable,
            "findings": self.findings,
            "withdrawn": self.withdrawn,
            "extended_rms_um": self.extended_rms_um,
            "extended_fit_rms_um": self.extended_fit_rms_um,
            "with_unmodelled_rms_um": self.with_unmodelled_rms_um,
            "gain_pct": {
                "x": pct(self.baseline_rms_um.x, self.extended_rms_um.x),
                "y": pct(self.baseline_rms_um.y, self.extended_rms_um.y),
            },
            "base_free_params": self.base_free_params,
            "base_fixed_params": self.base_fixed_params,
            "measured_axes": self.measured_axes,
            "measured_from": self.measured_from,
            "synthetic_time": self.synthetic_time,
            "time_with": self.time_with.map(|(a, r)| serde_json::json!({"axis": a, "r": r})),
            "time_unusable": self.time_unusable,
            "grid": self.grid,
            "map_term": self.map_term,
            "frame_turn_urad": self.frame_turn_urad,
            "whole_cycle_folds": self.whole_cycle_folds,
            "folds_interleaved": self.folds_interleaved,
            "judged_points": self.judged_points,
            "aliased_contribution_rms_um": self.aliased_contribution_rms_um,
            "noise": self.noise,
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

/// Significant corrections listed in the text report (the rest: JSON).
const PARAMS_SHOWN: usize = 12;

/// A long list of parameter names, shortened to the first few.
fn abbreviate(names: &[String]) -> String {
    const SHOWN: usize = 4;
    let mut s = names
        .iter()
        .take(SHOWN)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > SHOWN {
        let _ = write!(s, ", … ({} more)", names.len() - SHOWN);
    }
    s
}

/// Discordant pairs shown in the text report (the rest are in the JSON).
const DISCORDANT_SHOWN: usize = 6;

/// One component's repeatability, its held readings, outliers,
/// discordant pairs and neighbour noise: what noise the residual is
/// judged against.
fn repeatability_text(c: &ComponentNoise) -> String {
    let mut out = String::new();
    let a = c.component;
    match (c.repeatability_um, c.max_s_um) {
        (Some(s), _) if c.repeatability_at_resolution => {
            let _ = writeln!(
                out,
                "  {a}: repeatability ≤ {s:.4} µm: the replicates scatter less than the log's resolution ({s:.4} µm), taken as the repeatability (a bound, not a measurement)"
            );
        }
        (Some(s), Some(m)) => {
            let _ = writeln!(
                out,
                "  {a}: repeatability σ {s:.4} µm pooled over {} replicated targets (max s_i {m:.4} µm)",
                c.replicated_targets - c.held_targets
            );
        }
        _ => {
            let _ = writeln!(out, "  {a}: no target visited twice (no replicates)");
        }
    }
    if let Some(h) = c.held_scatter_um {
        let _ = writeln!(
            out,
            "  {a}: {} replicated targets read while {a} was held still (the other axis positioning) scatter {h:.4} µm: not repeats of positioning {a}, left out of the repeatability",
            c.held_targets
        );
    }
    if !c.outliers.is_empty() {
        let firsts = c.outliers.iter().filter(|o| o.first_visit).count();
        let list = c
            .outliers
            .iter()
            .take(6)
            .map(|o| {
                format!(
                    "cycle {} {} at {:.1} µm ({:+.2} µm)",
                    o.cycle,
                    match o.approach {
                        v if v > 0.0 => "fwd",
                        v if v < 0.0 => "bwd",
                        _ => "?",
                    },
                    o.target_um,
                    o.excess_um
                )
            })
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            out,
            "  {a}: {} outlier visit(s) excluded (> {} robust σ from their target's median): {list}{}",
            c.outliers.len(),
            super::noise::OUTLIER_SIGMAS,
            if firsts == c.outliers.len() {
                " — each the first visit of its target: a first-approach effect (warm-up, settling, or an unlogged first move)"
            } else {
                ""
            }
        );
    }
    if !c.discordant_pairs.is_empty() {
        out.push_str(&discordant_text(c));
    }
    if let Some(nb) = c.neighbour_noise_um {
        let _ = writeln!(
            out,
            "  {a}: noise from neighbouring positions ≤ {nb:.4} µm; held-out residual rms {:.4} µm",
            c.heldout_rms_um
        );
    }
    out
}

/// What one component's residual leaves against its noise: the scatter
/// between visits and the per-target systematic error.
fn residual_noise_text(c: &ComponentNoise) -> String {
    let mut out = String::new();
    let a = c.component;
    if let (Some(sc), Some(nb)) = (
        c.residual_replicate_scatter_um,
        c.replicate_neighbour_noise_um,
    ) {
        if c.changes_between_visits {
            let _ = writeln!(
                out,
                "  {a}: UNEXPLAINED: visits of one target scatter {sc:.4} µm in the residual (robust), {:.1}× the noise between neighbouring positions of the same kind of pass ({nb:.4} µm): the error changes between visits (with time, or with the path to the target), which no function of position explains; the repeatability above is not the measurement's noise",
                sc / nb
            );
        } else {
            let _ = writeln!(
                out,
                "  {a}: visits of one target scatter {sc:.4} µm in the residual (robust), {:.1}× the noise between neighbouring positions of the same kind of pass ({nb:.4} µm)",
                sc / nb
            );
        }
    }
    if let (Some(sys), Some(floor), Some(ratio)) = (
        c.systematic_rms_um,
        c.systematic_noise_floor_um,
        c.systematic_over_repeatability,
    ) {
        // Per-target means can be explained while structure the
        // means average out (a drift from cycle to cycle) is not.
        let lacking: Vec<&str> = c
            .readings
            .iter()
            .filter(|r| r.model_explains == Some(false))
            .map(|r| r.kind.as_str())
            .collect();
        let _ = writeln!(
            out,
            "  {a}: {} {sys:.4} µm rms of per-target systematic error remains (held out), {ratio:.1}× the repeatability (noise alone would leave {floor:.4} µm){}",
            if c.unexplained { "UNEXPLAINED:" } else { "explained to the noise:" },
            if !c.unexplained && !lacking.is_empty() {
                format!(
                    "; the model still lacks {} (see the readings): the per-target means average it out",
                    lacking.join(", ")
                )
            } else {
                String::new()
            }
        );
    } else if let (Some(sys), Some(floor), true) = (
        c.systematic_rms_um,
        c.systematic_noise_floor_um,
        c.repeatability_at_resolution,
    ) {
        let _ = writeln!(
            out,
            "  {a}: {} {sys:.4} µm rms of per-target systematic error remains (held out); the repeatability is only bounded by the log's resolution, so no ratio to it is given (the resolution alone would leave {floor:.4} µm)",
            if c.unexplained { "UNEXPLAINED:" } else { "explained to the log's resolution:" }
        );
    } else if c.unexplained {
        let _ = writeln!(
            out,
            "  {a}: UNEXPLAINED: the held-out residual ({:.4} µm rms) is ≥ 3× the noise from neighbouring positions",
            c.heldout_rms_um
        );
    }
    out
}

/// The text report's line on a component's discordant pairs
/// ([`super::noise::DiscordantPair`]).
fn discordant_text(c: &super::noise::ComponentNoise) -> String {
    let a = c.component;
    let pairs = &c.discordant_pairs;
    let list = pairs
        .iter()
        .take(DISCORDANT_SHOWN)
        .map(|p| {
            format!(
                "{} at {:.1} µm, cycles {} and {}: {:+.3} µm apart ({:.0} σ)",
                match p.approach {
                    v if v > 0.0 => "fwd",
                    v if v < 0.0 => "bwd",
                    _ => "?",
                },
                p.target_um,
                p.cycles[0],
                p.cycles[1],
                p.difference_um,
                p.sigmas
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    let more = if pairs.len() > DISCORDANT_SHOWN {
        format!(
            " … {} more in the JSON report",
            pairs.len() - DISCORDANT_SHOWN
        )
    } else {
        String::new()
    };
    // A pair with a visit that opens a pass: where an approach move the
    // log does not hold would put the axis on the other side of its play.
    let opens = pairs
        .iter()
        .filter(|p| p.first_of_pass.iter().any(|&f| f))
        .count();
    let cause = if opens == pairs.len() {
        " — each has a visit that is the first of its pass: an approach move the log does not hold can leave the axis on the other side of its play than the logged path says (a log with an `approach` column is replayed with it)"
    } else {
        ""
    };
    if c.discordant_pairs_kept {
        format!(
            "  {a}: {} target(s) visited twice disagree by > {} robust σ: {list}{more}; too many (> {:.0} % of the two-visit targets) to be wild visits: the scatter is heavy-tailed and they stay in the repeatability{cause}\n",
            pairs.len(),
            super::noise::DISCORDANT_SIGMAS,
            100.0 * super::noise::MAX_DISCORDANT_SHARE
        )
    } else {
        format!(
            "  {a}: {} discordant pair(s) left out of the repeatability, the per-target means and the fit (targets visited twice whose visits disagree by > {} robust σ; which visit is wild cannot be told from two): {list}{more}{cause}\n",
            pairs.len(),
            super::noise::DISCORDANT_SIGMAS
        )
    }
}
