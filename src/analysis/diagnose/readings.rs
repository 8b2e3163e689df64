//! Structure read from the replicates, as a metrologist reads an ISO 230-2
//! test: lost motion and how it changes along the travel, the drive's scale
//! and non-linearity, drift from cycle to cycle, first-approach outliers.
//!
//! Why a file of its own: the model-term search (`search.rs`) needs dense
//! positions to place a period or a bump, so on a sparse test (5 targets ×
//! 5 cycles) it finds nothing even when the systematic error is many times
//! the repeatability. These readings need no model: each is a statistic of
//! the per-target means whose noise the replicates themselves give (pooled
//! `s`), tested with a χ² or a z against it. Each reading then says whether
//! the model's held-out residual still shows it (`model_explains`), so a
//! reader knows which structure the model carries and which it lacks.

use serde::Serialize;

use crate::model::Axis;

/// z (normal, or Wilson–Hilferty of a χ²) at or above which a reading is
/// reported.
pub const READING_Z: f64 = 3.0;

/// Targets up to which a reading lists its per-target values (an ISO
/// 230-2 plan has 5–11; a dense scan's list would be a table, not a
/// sentence).
const MAX_LISTED: usize = 12;

/// One visit of a replicated target (outliers excluded, see `noise.rs`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Visit {
    /// Target along the moving axis, µm.
    pub target_um: f64,
    /// Approach direction: `+1`, `−1`, `0` unknown.
    pub approach: f64,
    /// Cycle of the visit.
    pub cycle: u32,
    /// Deviation `meas − target`, µm (ISO 230-2 sign).
    pub dev_um: f64,
    /// Held-out residual of the model, µm (NaN when not judged).
    pub resid_um: f64,
}

/// What a reading is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ReadingKind {
    /// A reversal (lost motion) that is not zero on average.
    Reversal,
    /// A reversal that changes along the travel.
    ReversalVaries,
    /// The slope of the mean deviation against position.
    Scale,
    /// The mean deviation departs from a straight line.
    Nonlinearity,
    /// The mean deviation of a cycle changes from cycle to cycle.
    CycleDrift,
    /// A first visit far from the other visits of its target.
    FirstApproach,
}

impl ReadingKind {
    /// Snake-case name (as in JSON).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Reversal => "reversal",
            Self::ReversalVaries => "reversal_varies",
            Self::Scale => "scale",
            Self::Nonlinearity => "nonlinearity",
            Self::CycleDrift => "cycle_drift",
            Self::FirstApproach => "first_approach",
        }
    }

    fn cause(self) -> &'static str {
        match self {
            Self::Reversal => {
                "play in the nut or the coupling, or elastic wind-up of the drive train against friction"
            }
            Self::ReversalVaries => {
                "nut preload or wear that varies along the screw, a bent screw or misaligned coupling whose wind-up changes with position, or guide friction that varies; one constant play cannot remove it, a per-target reversal (bidirectional) table can"
            }
            Self::Scale => {
                "cumulative lead error of the screw, thermal expansion of the screw against the reference, or a scale (cosine) error of the reference sensor's alignment"
            }
            Self::Nonlinearity => {
                "progressive pitch error of the screw, a worn or bent section, or guide straightness seen through an Abbe offset"
            }
            Self::CycleDrift => {
                "thermal growth of the screw or the frame as the motor warms, or drift of the reference sensor"
            }
            Self::FirstApproach => {
                "warm-up, stiction after rest, or an unlogged first move (homing, overtravel) that leaves a different preload"
            }
        }
    }
}

/// One piece of structure read from the replicates.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reading {
    /// What it is.
    pub kind: ReadingKind,
    /// The error component (the measured axis).
    pub component: Axis,
    /// Its size, µm (`ppm` for `scale`): the mean reversal, the largest
    /// change of the reversal along the travel, the slope, the largest
    /// departure from the straight line, the change over the cycles, the
    /// outlier's excess.
    pub value: f64,
    /// Unit of `value`.
    pub unit: &'static str,
    /// Its significance: z against the replicates' noise (Wilson–Hilferty
    /// z for the χ² readings).
    pub z: f64,
    /// Whether the model's held-out residual no longer shows it (`None`
    /// when the residual cannot say, e.g. an outlier).
    pub model_explains: Option<bool>,
    /// A sentence a person understands.
    pub sentence: String,
    /// The likely physical causes.
    pub cause: &'static str,
    /// The model term this reading becomes and what it gains on held-out
    /// data (reversal that varies, non-linearity), or why no term can
    /// carry it (first approach); absent for readings the model's own
    /// parameters carry (reversal, scale, drift).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub term: Option<ReadingTerm>,
}

/// A reading as a model term: the term, its held-out test, and whether the
/// extended model carries it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReadingTerm {
    /// Term kind (`position_table`), empty when no term can carry it.
    pub kind: &'static str,
    /// Name of the term in the extended model (empty when not added).
    pub name: String,
    /// Knots of the table (its targets, or evenly spaced on a dense axis).
    pub knots: usize,
    /// Held-out RMS of the component without the term, µm (NaN when not
    /// tested).
    pub heldout_rms_before_um: f64,
    /// ... and with it, µm.
    pub heldout_rms_after_um: f64,
    /// `100·(1 − after/before)`, % (negative: the term predicts held-out
    /// data worse, it does not generalize).
    pub gain_pct: f64,
    /// Paired z of the held-out reduction of squared error.
    pub z: f64,
    /// Whether the extended model carries it (it passed the same held-out
    /// test as every finding).
    pub in_extended_model: bool,
    /// What the test says, in words.
    pub sentence: String,
}

/// What a reversal reading says when a target's approaches stopped at
/// different positions (`widest_um` apart at most): they are paired.
fn paired(widest_um: f64) -> String {
    if widest_um > 1e-3 {
        format!(
            "; the forward and backward arrivals of a target stop up to {widest_um:.1} µm apart and are paired as one target (as the test's own report pairs them): a change of the error over that distance counts as reversal"
        )
    } else {
        String::new()
    }
}

/// Normal z of a χ² statistic with `k` degrees of freedom (Wilson–Hilferty).
pub(super) fn wilson_hilferty(chi2: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return 0.0;
    }
    let v = 2.0 / (9.0 * k);
    ((chi2 / k).cbrt() - (1.0 - v)) / v.sqrt()
}

/// Mean of one (target, approach) group: deviation and residual means, n.
#[derive(Debug, Clone, Copy)]
struct Group {
    target_um: f64,
    approach: f64,
    n: f64,
    dev: f64,
    resid: f64,
}

fn groups(visits: &[Visit]) -> Vec<Group> {
    let mut out: Vec<(f64, f64, Vec<&Visit>)> = Vec::new();
    for v in visits {
        match out
            .iter_mut()
            .find(|(t, a, _)| (t - v.target_um).abs() < 1e-3 && *a == v.approach)
        {
            Some((_, _, g)) => g.push(v),
            None => out.push((v.target_um, v.approach, vec![v])),
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    out.into_iter()
        .filter(|(_, _, g)| g.len() >= 2)
        .map(|(t, a, g)| {
            let n = g.len() as f64;
            let res: Vec<f64> = g
                .iter()
                .map(|v| v.resid_um)
                .filter(|r| r.is_finite())
                .collect();
            Group {
                target_um: t,
                approach: a,
                n,
                dev: g.iter().map(|v| v.dev_um).sum::<f64>() / n,
                resid: if res.len() == g.len() {
                    res.iter().sum::<f64>() / n
                } else {
                    f64::NAN
                },
            }
        })
        .collect()
}

/// Weighted straight line `y = a + b·x` (weights `w`): `(a, b, var_b,
/// residuals)`; `None` when degenerate.
fn line(x: &[f64], y: &[f64], w: &[f64]) -> Option<(f64, f64, f64, Vec<f64>)> {
    let sw: f64 = w.iter().sum();
    if x.len() < 2 || sw <= 0.0 {
        return None;
    }
    let mx = x.iter().zip(w).map(|(a, b)| a * b).sum::<f64>() / sw;
    let my = y.iter().zip(w).map(|(a, b)| a * b).sum::<f64>() / sw;
    let sxx: f64 = x.iter().zip(w).map(|(a, b)| b * (a - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let sxy: f64 = x
        .iter()
        .zip(y)
        .zip(w)
        .map(|((a, c), b)| b * (a - mx) * (c - my))
        .sum();
    let slope = sxy / sxx;
    let a = my - slope * mx;
    let res = x.iter().zip(y).map(|(p, q)| q - a - slope * p).collect();
    Some((a, slope, 1.0 / sxx, res))
}

/// The readings of one component from its replicated visits and pooled
/// repeatability `s_um`; `outliers` are `(cycle, target_um, excess_um,
/// first_visit)` of the visits left out.
pub(super) fn read(
    component: Axis,
    visits: &[Visit],
    s_um: f64,
    outliers: &[(u32, f64, f64, bool)],
) -> Vec<Reading> {
    let mut out = Vec::new();
    if !(s_um.is_finite() && s_um > 0.0) {
        return out;
    }
    let r = Replicates::new(component, visits, s_um);
    r.reversal(&mut out);
    r.mean_deviation(&mut out);
    r.cycle_drift(&mut out);
    r.first_approaches(outliers, &mut out);
    out
}

/// One component's visits grouped by target and approach, shared by the
/// readings [`read`] takes from them.
struct Replicates<'a> {
    component: Axis,
    visits: &'a [Visit],
    s_um: f64,
    /// `s_um²`: the variance of one visit.
    s2: f64,
    gs: Vec<Group>,
    targets: super::data::Targets,
    /// Each group's target.
    gid: Vec<usize>,
    /// The groups of each target, in order of first appearance.
    members: Vec<Vec<usize>>,
    /// A target's index in `members`.
    slot: std::collections::HashMap<usize, usize>,
    /// The range of the targets, for the unit positions are written in.
    lo_t: f64,
    hi_t: f64,
}

impl<'a> Replicates<'a> {
    fn new(component: Axis, visits: &'a [Visit], s_um: f64) -> Self {
        let s2 = s_um * s_um;
        let gs = groups(visits);
        let (lo_t, hi_t) = visits
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v.target_um), b.max(v.target_um))
            });
        // The targets the groups stand for: the approaches of one target may
        // stop at slightly different positions (`data::targets_of`).
        let mut tpos: Vec<f64> = gs.iter().map(|g| g.target_um).collect();
        tpos.sort_by(f64::total_cmp);
        tpos.dedup_by(|p, q| (*p - *q).abs() < 1e-3);
        let targets = super::data::targets_of(&tpos);
        // Each group's target (every group position is one of `tpos`, so it
        // has one; a group that had none would stand alone), and the groups of
        // each target in order of first appearance: one pass, not one search
        // per pair of groups (a dense log has a thousand groups).
        let gid: Vec<usize> = gs
            .iter()
            .enumerate()
            .map(|(k, g)| {
                targets
                    .index_of(g.target_um)
                    .unwrap_or(targets.bounds.len() + k)
            })
            .collect();
        let mut members: Vec<Vec<usize>> = Vec::new();
        let mut slot: std::collections::HashMap<usize, usize> = std::collections::HashMap::new();
        for (k, &t) in gid.iter().enumerate() {
            let j = *slot.entry(t).or_insert_with(|| {
                members.push(Vec::new());
                members.len() - 1
            });
            members[j].push(k);
        }
        Replicates {
            component,
            visits,
            s_um,
            s2,
            gs,
            targets,
            gid,
            members,
            slot,
            lo_t,
            hi_t,
        }
    }

    /// Positions in mm on long travels, in µm on short ones (a flexure's
    /// 450 µm would read as "0.4 mm" everywhere).
    fn at(&self, t: f64) -> String {
        if self.hi_t - self.lo_t >= 10_000.0 {
            format!("{:.1} mm", t / 1e3)
        } else {
            format!("{t:.1} µm")
        }
    }

    /// Reversal per target: B_i = x̄↑ − x̄↓ (ISO 230-2 sign), as
    /// `(target, B, var, B of residual)`.
    fn reversals(&self) -> Vec<(f64, f64, f64, f64)> {
        let (gs, s2) = (&self.gs, self.s2);
        let mut rev: Vec<(f64, f64, f64, f64)> = Vec::new();
        for (k, g) in gs.iter().enumerate().filter(|(_, g)| g.approach > 0.0) {
            let here = self
                .slot
                .get(&self.gid[k])
                .map_or(&[][..], |&j| &self.members[j][..]);
            if let Some(h) = here.iter().map(|&i| &gs[i]).find(|h| h.approach < 0.0) {
                rev.push((
                    g.target_um,
                    g.dev - h.dev,
                    s2 * (1.0 / g.n + 1.0 / h.n),
                    g.resid - h.resid,
                ));
            }
        }
        rev
    }

    /// The mean reversal, and whether it changes along the travel.
    fn reversal(&self, out: &mut Vec<Reading>) {
        let (component, name) = (self.component, self.component.as_str());
        let rev = self.reversals();
        if rev.len() < 2 {
            return;
        }
        let sw: f64 = rev.iter().map(|r| 1.0 / r.2).sum();
        let mean = rev.iter().map(|r| r.1 / r.2).sum::<f64>() / sw;
        let z = mean.abs() * sw.sqrt();
        let res_mean = rev.iter().map(|r| r.3 / r.2).sum::<f64>() / sw;
        let res_z = res_mean.abs() * sw.sqrt();
        if z >= READING_Z {
            out.push(Reading {
                kind: ReadingKind::Reversal,
                component,
                value: mean,
                unit: "µm",
                z,
                model_explains: res_mean.is_finite().then_some(res_z < READING_Z),
                sentence: format!(
                    "{name} reverses with a lost motion of {:+.3} µm on average (> 0: the platform trails the command in both directions, < 0: it runs ahead); in ISO 230-2's sign the mean reversal B̄ = mean of x̄↑ − x̄↓ (measured − target) = {mean:+.3} ± {:.3} µm over {} targets (outliers left out){}",
                    -mean,
                    sw.sqrt().recip(),
                    rev.len(),
                    paired(self.targets.widest_um())
                ),
                term: None,
                cause: ReadingKind::Reversal.cause(),
            });
        }
        if rev.len() >= 3 {
            self.reversal_varies(&rev, mean, res_mean, out);
        }
    }

    /// Whether the reversals `rev` scatter about their mean `mean` (that
    /// of the residual: `res_mean`) more than the noise explains.
    fn reversal_varies(
        &self,
        rev: &[(f64, f64, f64, f64)],
        mean: f64,
        res_mean: f64,
        out: &mut Vec<Reading>,
    ) {
        let (component, name) = (self.component, self.component.as_str());
        let chi2: f64 = rev.iter().map(|r| (r.1 - mean).powi(2) / r.2).sum();
        let zv = wilson_hilferty(chi2, (rev.len() - 1) as f64);
        if zv < READING_Z {
            return;
        }
        let res_ok = rev.iter().all(|r| r.3.is_finite());
        let res_chi2: f64 = rev.iter().map(|r| (r.3 - res_mean).powi(2) / r.2).sum();
        let (lo, hi) = rev.iter().fold((rev[0], rev[0]), |(lo, hi), r| {
            (
                if r.1 < lo.1 { *r } else { lo },
                if r.1 > hi.1 { *r } else { hi },
            )
        });
        out.push(Reading {
            kind: ReadingKind::ReversalVaries,
            component,
            value: hi.1 - lo.1,
            unit: "µm",
            z: zv,
            model_explains: res_ok
                .then(|| wilson_hilferty(res_chi2, (rev.len() - 1) as f64) < READING_Z),
            sentence: format!(
                "{name}'s lost motion changes along the travel: B = {:+.3} µm at {}, {:+.3} µm at {} ({} targets; noise alone would leave about ± {:.3} µm){}",
                lo.1,
                self.at(lo.0),
                hi.1,
                self.at(hi.0),
                rev.len(),
                (rev.iter().map(|r| r.2).sum::<f64>() / rev.len() as f64).sqrt(),
                if rev.len() <= MAX_LISTED {
                    format!(
                        "; B_i = x̄↑ − x̄↓ (measured − target, outliers left out): {}; the lost motion is −B_i{}",
                        rev.iter()
                            .map(|r| format!("{:+.3} µm at {}", r.1, self.at(r.0)))
                            .collect::<Vec<_>>()
                            .join(", "),
                        paired(self.targets.widest_um())
                    )
                } else {
                    String::new()
                }
            ),
            term: None,
            cause: ReadingKind::ReversalVaries.cause(),
        });
    }

    /// The bidirectional mean deviation per target (ISO 230-2's x̄_i: the
    /// mean over the approaches of each approach's mean, so a reversal,
    /// constant or varying, cancels) of the targets whose means compare,
    /// or `None` when too few do.
    fn target_means(&self) -> Option<Means> {
        let (gs, s2) = (&self.gs, self.s2);
        // (target, x̄, var, residual x̄) and the approaches it was seen from.
        let mut tg: Vec<(f64, f64, f64, f64)> = Vec::new();
        let mut napp: Vec<usize> = Vec::new();
        for here in self.members.iter().map(|m| m.iter().map(|&i| &gs[i])) {
            let here: Vec<&Group> = here.collect();
            let k = here.len() as f64;
            tg.push((
                here.iter().map(|h| h.target_um).sum::<f64>() / k,
                here.iter().map(|h| h.dev).sum::<f64>() / k,
                s2 * here.iter().map(|h| 1.0 / h.n).sum::<f64>() / (k * k),
                here.iter().map(|h| h.resid).sum::<f64>() / k,
            ));
            napp.push(here.len());
        }
        // Only targets seen from the same approaches have comparable means:
        // those seen from the most (both ways, when any is). The turning
        // points of a step test (its first and last target, reached one way
        // only) are left out rather than the whole reading.
        let most = napp.iter().copied().max().unwrap_or(0);
        let all = tg.len();
        let tg: Vec<(f64, f64, f64, f64)> = tg
            .into_iter()
            .zip(&napp)
            .filter(|(_, &n)| n == most)
            .map(|(t, _)| t)
            .collect();
        if !(tg.len() >= 3 && all - tg.len() <= 2) {
            return None;
        }
        let x: Vec<f64> = tg.iter().map(|t| t.0).collect();
        let y: Vec<f64> = tg.iter().map(|t| t.1).collect();
        let yr: Vec<f64> = tg.iter().map(|t| t.3).collect();
        let w: Vec<f64> = tg.iter().map(|t| 1.0 / t.2).collect();
        let res_ok = yr.iter().all(|v| v.is_finite());
        let span = x[x.len() - 1] - x[0];
        Some(Means {
            tg,
            x,
            y,
            yr,
            w,
            res_ok,
            span,
        })
    }

    /// Scale and non-linearity of the bidirectional mean deviation per
    /// target.
    fn mean_deviation(&self, out: &mut Vec<Reading>) {
        let Some(m) = self.target_means() else {
            return;
        };
        if let Some((_, b, var_b, resid)) = line(&m.x, &m.y, &m.w) {
            self.scale(&m, b, var_b, out);
            self.nonlinearity(&m, &resid, out);
        }
    }

    /// The slope `b` (variance `var_b`) of the line through the means.
    fn scale(&self, m: &Means, b: f64, var_b: f64, out: &mut Vec<Reading>) {
        let (component, name) = (self.component, self.component.as_str());
        let z = b.abs() / var_b.sqrt();
        if z < READING_Z {
            return;
        }
        let rz = line(&m.x, &m.yr, &m.w).map(|(_, br, _, _)| br.abs() / var_b.sqrt());
        out.push(Reading {
            kind: ReadingKind::Scale,
            component,
            value: b * 1e6,
            unit: "ppm",
            z,
            model_explains: rz.filter(|_| m.res_ok).map(|r| r < READING_Z),
            sentence: format!(
                "{name}'s mean deviation grows by {:+.1} ± {:.1} ppm of the travel ({:+.3} µm over the {:.1} mm tested)",
                b * 1e6,
                var_b.sqrt() * 1e6,
                b * m.span,
                m.span / 1e3
            ),
            term: None,
            cause: ReadingKind::Scale.cause(),
        });
    }

    /// The means' departure `resid` from their line, when the noise does
    /// not explain it.
    fn nonlinearity(&self, m: &Means, resid: &[f64], out: &mut Vec<Reading>) {
        let (component, name) = (self.component, self.component.as_str());
        let (x, y, w) = (&m.x, &m.y, &m.w);
        let dof = m.tg.len() as f64 - 2.0;
        if dof < 2.0 {
            return;
        }
        let chi2: f64 = resid.iter().zip(w).map(|(r, w)| r * r * w).sum();
        let zn = wilson_hilferty(chi2, dof);
        if zn < READING_Z {
            return;
        }
        let k = (0..resid.len())
            .max_by(|&a, &b| resid[a].abs().total_cmp(&resid[b].abs()))
            .unwrap_or(0);
        let rz = line(x, &m.yr, w).map(|(_, _, _, rr)| {
            wilson_hilferty(rr.iter().zip(w).map(|(r, w)| r * r * w).sum(), dof)
        });
        out.push(Reading {
            kind: ReadingKind::Nonlinearity,
            component,
            value: resid[k],
            unit: "µm",
            z: zn,
            model_explains: rz.filter(|_| m.res_ok).map(|r| r < READING_Z),
            sentence: format!(
                "{name}'s mean deviation departs from a straight line by up to {:+.3} µm (at {}; the least-squares line through the bidirectional means x̄_i, measured − target; noise alone ± {:.3} µm per target){}",
                resid[k],
                self.at(x[k]),
                m.tg[k].2.sqrt(),
                if x.len() <= MAX_LISTED {
                    let n = x.len() - 1;
                    let chord = |i: usize| {
                        y[i] - y[0] - (y[n] - y[0]) * (x[i] - x[0]) / (x[n] - x[0])
                    };
                    format!(
                        "; x̄_i less that line: {}; less the chord through the end targets (how a table zero at its end knots reads it): {}",
                        (0..x.len())
                            .map(|i| format!("{:+.3} µm at {}", resid[i], self.at(x[i])))
                            .collect::<Vec<_>>()
                            .join(", "),
                        (0..x.len())
                            .map(|i| format!("{:+.3}", chord(i)))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                } else {
                    String::new()
                }
            ),
            term: None,
            cause: ReadingKind::Nonlinearity.cause(),
        });
    }

    /// Drift from cycle to cycle: each visit's deviation from its group's
    /// mean (the target's systematic error cancels), averaged per cycle.
    fn cycle_drift(&self, out: &mut Vec<Reading>) {
        let (component, name) = (self.component, self.component.as_str());
        let (gs, s2) = (&self.gs, self.s2);
        let mut cycles: Vec<(u32, f64, f64, f64)> = Vec::new(); // (cycle, Σe, n, Σe of residual)
        for v in self.visits {
            let Some(g) = gs
                .iter()
                .find(|g| (g.target_um - v.target_um).abs() < 1e-3 && g.approach == v.approach)
            else {
                continue;
            };
            let (e, er) = (v.dev_um - g.dev, v.resid_um - g.resid);
            match cycles.iter_mut().find(|c| c.0 == v.cycle) {
                Some(c) => {
                    c.1 += e;
                    c.2 += 1.0;
                    c.3 += er;
                }
                None => cycles.push((v.cycle, e, 1.0, er)),
            }
        }
        cycles.sort_by_key(|c| c.0);
        if cycles.len() < 3 {
            return;
        }
        let x: Vec<f64> = cycles.iter().map(|c| c.0 as f64).collect();
        let y: Vec<f64> = cycles.iter().map(|c| c.1 / c.2).collect();
        let yr: Vec<f64> = cycles.iter().map(|c| c.3 / c.2).collect();
        let w: Vec<f64> = cycles.iter().map(|c| c.2 / s2).collect();
        let Some((_, b, var_b, _)) = line(&x, &y, &w) else {
            return;
        };
        let z = b.abs() / var_b.sqrt();
        if z < READING_Z {
            return;
        }
        let span = x[x.len() - 1] - x[0];
        let rz = line(&x, &yr, &w).map(|(_, br, _, _)| br.abs() / var_b.sqrt());
        out.push(Reading {
            kind: ReadingKind::CycleDrift,
            component,
            value: b * span,
            unit: "µm",
            z,
            model_explains: rz.filter(|r| r.is_finite()).map(|r| r < READING_Z),
            sentence: format!(
                "{name} drifts from cycle to cycle: {:+.3} ± {:.3} µm per cycle, {:+.3} µm over cycles {} to {}",
                b,
                var_b.sqrt(),
                b * span,
                cycles[0].0,
                cycles[cycles.len() - 1].0
            ),
            term: None,
            cause: ReadingKind::CycleDrift.cause(),
        });
    }

    /// First visits that stand apart (found in `noise.rs`).
    fn first_approaches(&self, outliers: &[(u32, f64, f64, bool)], out: &mut Vec<Reading>) {
        let (component, name) = (self.component, self.component.as_str());
        for &(cycle, target_um, excess_um, first) in outliers {
            if first {
                out.push(Reading {
                    kind: ReadingKind::FirstApproach,
                    component,
                    value: excess_um,
                    unit: "µm",
                    z: excess_um.abs() / self.s_um,
                    model_explains: None,
                    sentence: format!(
                        "the first visit of {} on {name} (cycle {cycle}) is {excess_um:+.3} µm from the other visits of that target",
                        self.at(target_um)
                    ),
                    term: None,
                    cause: ReadingKind::FirstApproach.cause(),
                });
            }
        }
    }
}

/// The bidirectional means of the targets a scale and non-linearity are
/// read from.
struct Means {
    /// `(target, x̄, var, residual x̄)` per target.
    tg: Vec<(f64, f64, f64, f64)>,
    x: Vec<f64>,
    y: Vec<f64>,
    /// The residual's x̄: whether the model explains the reading.
    yr: Vec<f64>,
    /// Weights, 1 / var.
    w: Vec<f64>,
    res_ok: bool,
    /// The targets' span, µm.
    span: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// An ISO 230-2 test (targets × cycles × both approaches) of an axis
    /// whose deviation is `f(target, approach, cycle)` plus N(0, s).
    fn iso(rng: &mut ChaCha8Rng, s: f64, f: &dyn Fn(f64, f64, u32) -> f64) -> Vec<Visit> {
        let mut v = Vec::new();
        for cycle in 1..=5u32 {
            for approach in [1.0, -1.0] {
                for k in 0..6 {
                    let t = 1000.0 + 9000.0 * k as f64 / 5.0;
                    let e: f64 = (0..12).map(|_| rng.gen::<f64>()).sum::<f64>() - 6.0;
                    let dev = f(t, approach, cycle) + s * e;
                    v.push(Visit {
                        target_um: t,
                        approach,
                        cycle,
                        dev_um: dev,
                        resid_um: dev,
                    });
                }
            }
        }
        v
    }

    /// Deviation as a function of (target, approach, cycle).
    type Shape = Box<dyn Fn(f64, f64, u32) -> f64>;

    fn kinds(r: &[Reading]) -> Vec<ReadingKind> {
        r.iter().map(|r| r.kind).collect()
    }

    #[test]
    fn clean_axes_give_almost_no_readings() {
        // 200 axes with only noise (random σ): each of the ~4 tests at
        // z ≥ 3 fires by chance about 0.1–0.3 % of the time.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut false_readings = 0;
        for _ in 0..200 {
            let s = 0.05 + 3.0 * rng.gen::<f64>();
            let v = iso(&mut rng, s, &|_, _, _| 0.0);
            false_readings += read(Axis::X, &v, s, &[]).len();
        }
        assert!(false_readings <= 4, "{false_readings} false readings");
    }

    #[test]
    fn each_structure_is_read_and_only_it() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for case in 0..40 {
            let s = 0.05 + 2.0 * rng.gen::<f64>();
            let size = s * (3.0 + 10.0 * rng.gen::<f64>());
            let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
            let a = sign * size;
            let (want, f): (ReadingKind, Shape) = match case % 5 {
                0 => (ReadingKind::Reversal, Box::new(move |_, d, _| 0.5 * a * d)),
                1 => (
                    ReadingKind::ReversalVaries,
                    Box::new(move |t, d, _| 0.5 * d * a * ((t - 5500.0) / 4500.0)),
                ),
                2 => (
                    ReadingKind::Scale,
                    Box::new(move |t, _, _| a * (t - 5500.0) / 4500.0),
                ),
                3 => (
                    ReadingKind::Nonlinearity,
                    Box::new(move |t, _, _| a * (((t - 5500.0) / 4500.0).powi(2) - 0.4)),
                ),
                _ => (
                    ReadingKind::CycleDrift,
                    Box::new(move |_, _, c| a * (c as f64 - 3.0) / 2.0),
                ),
            };
            let v = iso(&mut rng, s, &f);
            let r = read(Axis::X, &v, s, &[]);
            let k = kinds(&r);
            assert!(k.contains(&want), "case {case}: {want:?} not read: {r:#?}");
            // A reversal that varies linearly also has a mean of zero here;
            // the others must not leak into unrelated readings.
            for other in &k {
                let related = *other == want
                    || (want == ReadingKind::ReversalVaries && *other == ReadingKind::Reversal);
                assert!(
                    related,
                    "case {case}: {want:?} also read as {other:?}: {r:#?}"
                );
            }
            let got = r
                .iter()
                .find(|r| r.kind == want)
                .map(|r| r.value)
                .unwrap_or(0.0);
            assert!(
                got.signum() == sign
                    || want == ReadingKind::ReversalVaries
                    || want == ReadingKind::Nonlinearity,
                "case {case}: sign of {want:?} is {got}"
            );
            // The residual equals the deviation here: the "model" explains nothing.
            assert!(r.iter().all(|r| r.model_explains == Some(false)));
        }
    }

    #[test]
    fn a_residual_without_the_structure_is_explained() {
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let mut v = iso(&mut rng, 0.5, &|_, d, _| 3.0 * d);
        for x in &mut v {
            x.resid_um = x.dev_um - 3.0 * x.approach;
        }
        let r = read(Axis::X, &v, 0.5, &[]);
        assert_eq!(kinds(&r), vec![ReadingKind::Reversal]);
        assert_eq!(r[0].model_explains, Some(true));
        assert!((r[0].value - 6.0).abs() < 0.5, "{}", r[0].value);
    }

    #[test]
    fn degenerate_input_gives_nothing_and_no_panic() {
        assert!(read(Axis::X, &[], 1.0, &[]).is_empty());
        let v = vec![
            Visit {
                target_um: f64::NAN,
                approach: 1.0,
                cycle: 1,
                dev_um: f64::INFINITY,
                resid_um: f64::NAN,
            };
            4
        ];
        let _ = read(Axis::X, &v, 1.0, &[]);
        assert!(read(Axis::X, &v, 0.0, &[]).is_empty());
        assert!(read(Axis::X, &v, f64::NAN, &[]).is_empty());
    }
}
