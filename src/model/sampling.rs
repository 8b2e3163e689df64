//! What a log's sampling can resolve, and why a fit could not identify
//! parameters: grouped by cause, with what would identify them, computed
//! from the log's step and each periodic term's period (Nyquist).
//!
//! Why here: a model table's fit ([`super::fit`]) lists the parameters the
//! data cannot determine by name (33 of them on a 100 µm-step log of the
//! default model); a person needs the cause and the remedy — "a 100 µm step
//! cannot resolve a 400 µm pitch's third harmonic (133 µm): sample at ≤
//! 33 µm" — once per term, not a line per parameter (issue 33).

use super::fit::Sample;
use super::{Axis, StageModel};
use serde::Serialize;

/// Share of an axis's span that the gaps up to the sampling spacing must
/// cover (see [`sampling_spacing_um`]).
const COVERED_SPAN: f64 = 0.9;

/// The spacing at which sorted positions `pos` sample their span: the
/// smallest gap `g` such that the gaps no longer than `g` add up to
/// [`COVERED_SPAN`] of the span (`None` with fewer than two positions).
///
/// Why not the median gap: positions in clusters (a test whose backward
/// targets sit 0.2 mm from its forward ones, 10 mm apart) have a median
/// gap of 0.2 mm, yet a period of 0.4 mm is sampled at two points per
/// 10 mm; fitted there, a screw harmonic becomes an arbitrary per-target
/// correction. On an even grid (with a few holes) this is the step.
pub fn sampling_spacing_um(pos: &[f64]) -> Option<f64> {
    if pos.len() < 2 {
        return None;
    }
    let span = pos[pos.len() - 1] - pos[0];
    let mut gaps: Vec<f64> = pos.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    let mut covered = 0.0;
    for &g in &gaps {
        covered += g;
        if covered >= COVERED_SPAN * span {
            return Some(g);
        }
    }
    gaps.last().copied()
}

/// Samples per period a remedy asks for: two is Nyquist's bare minimum,
/// at which a sine falls on its zeros; four separate sine from cosine
/// whatever the phase.
pub const SAMPLES_PER_PERIOD: f64 = 4.0;

/// The step that resolves a period of `period_um`: a
/// [`SAMPLES_PER_PERIOD`]th of it.
pub fn resolving_step_um(period_um: f64) -> f64 {
    period_um / SAMPLES_PER_PERIOD
}

/// Unidentifiable parameters of one cause.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UnidentifiableGroup {
    /// The term they belong to; `None` for the group of parameters from
    /// several terms that the log measures only in combination.
    pub term: Option<String>,
    /// Their full names (`x_cyclic.forward_sin_3_um`).
    pub params: Vec<String>,
    /// The cause and what would identify them, in words and numbers.
    pub advice: String,
}

/// The harmonic number of a periodic parameter (`forward_sin_3_um` → 3,
/// `cos_1_urad` → 1), `None` for any other parameter.
fn harmonic(param: &str) -> Option<u32> {
    let parts: Vec<&str> = param.split('_').collect();
    parts
        .windows(2)
        .find(|w| w[0] == "sin" || w[0] == "cos")
        .and_then(|w| w[1].parse().ok())
}

/// The frequency of harmonic `k` of `period_um` as the samples every
/// `step_um` see it, in cycles per sample folded into [0, ½]: harmonics
/// with the same folded frequency are indistinguishable.
fn folded(k: u32, period_um: f64, step_um: f64) -> f64 {
    let f = (f64::from(k) * step_um / period_um).rem_euclid(1.0);
    f.min(1.0 - f)
}

/// Distinct commanded positions of `axis` over `samples` (within 1 nm),
/// sorted.
fn positions(samples: &[Sample], axis: Axis) -> Vec<f64> {
    let mut p: Vec<f64> = samples.iter().map(|s| s.state.cmd_um(axis)).collect();
    p.sort_by(f64::total_cmp);
    p.dedup_by(|a, b| (*a - *b).abs() < 1e-3);
    p
}

/// `1, 2 and 3`.
fn and_list<T: std::fmt::Display>(items: &[T]) -> String {
    let s: Vec<String> = items.iter().map(ToString::to_string).collect();
    match s.as_slice() {
        [] => String::new(),
        [one] => one.clone(),
        [head @ .., last] => format!("{} and {last}", head.join(", ")),
    }
}

/// A length for a sentence: whole µm from 100 µm on, else 3 significant
/// digits.
fn len_um(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0} µm")
    } else if v.abs() >= 10.0 {
        format!("{v:.1} µm")
    } else {
        format!("{v:.2} µm")
    }
}

/// Why a periodic term's harmonics `ks` (of period `period_um` along
/// `axis`) are unidentifiable on samples every `step_um` over `span_um`,
/// and the step or scan that would identify them.
fn periodic_advice(
    term: &str,
    axis: Axis,
    period_um: f64,
    ks: &[u32],
    step_um: Option<f64>,
    span_um: f64,
) -> String {
    let Some(step) = step_um else {
        return format!(
            "{term}: harmonics {} of the {} period along {axis}: the log holds fewer than two positions of {axis}; scan {axis} over at least one period at ≤ {} steps",
            and_list(ks),
            len_um(period_um),
            len_um(resolving_step_um(period_um / f64::from(ks.iter().copied().max().unwrap_or(1))))
        );
    };
    if period_um > 2.0 * span_um {
        return format!(
            "{term}: the {} period along {axis} is more than twice the {} the log spans: its harmonics {} cannot be told from a slope; scan at least one {} period of {axis}",
            len_um(period_um),
            len_um(span_um),
            and_list(ks),
            len_um(period_um)
        );
    }
    // At or beyond Nyquist: step ≥ half the harmonic's period.
    let beyond: Vec<u32> = ks
        .iter()
        .copied()
        .filter(|&k| step >= period_um / f64::from(k) / 2.0 - 1e-9)
        .collect();
    if beyond.is_empty() {
        return format!(
            "{term}: harmonics {} of the {} period along {axis} are resolved by the {} step, yet the log cannot separate them from other parameters (`micropos diagnose LOG` names the combinations)",
            and_list(ks),
            len_um(period_um),
            len_um(step)
        );
    }
    let periods: Vec<String> = beyond
        .iter()
        .map(|&k| len_um(period_um / f64::from(k)))
        .collect();
    let mut s = format!(
        "{term}: a step of {} along {axis} cannot resolve the {} period's harmonic{} {} (period{} {}: a period needs a step shorter than half of it)",
        len_um(step),
        len_um(period_um),
        if beyond.len() == 1 { "" } else { "s" },
        and_list(&beyond),
        if beyond.len() == 1 { "" } else { "s" },
        and_list(&periods)
    );
    // Resolvable harmonics lost only because a short one folds onto them.
    let folded_onto: Vec<String> = ks
        .iter()
        .copied()
        .filter(|k| !beyond.contains(k))
        .filter_map(|k| {
            let by: Vec<u32> = beyond
                .iter()
                .copied()
                .filter(|&j| (folded(j, period_um, step) - folded(k, period_um, step)).abs() < 1e-6)
                .collect();
            (!by.is_empty()).then(|| {
                format!(
                    "{k} (harmonic {} folds onto it at this step)",
                    and_list(&by)
                )
            })
        })
        .collect();
    if !folded_onto.is_empty() {
        s.push_str(&format!(
            "; harmonic {} is lost with them",
            and_list(&folded_onto)
        ));
    }
    let shortest = period_um / f64::from(beyond.iter().copied().max().unwrap_or(1));
    s.push_str(&format!(
        ". Sample {axis} at ≤ {} / {SAMPLES_PER_PERIOD:.0} = {}, or add a dense segment ({} steps over one {} period)",
        len_um(shortest),
        len_um(resolving_step_um(shortest)),
        len_um(resolving_step_um(shortest)),
        len_um(period_um)
    ));
    s
}

/// The parameters `names` a fit of `model` to `samples` could not identify
/// (the fit report's `unidentifiable`), grouped: per periodic term, with
/// the step the samples have and the one its harmonics need; the
/// temperature coefficients of a log at one temperature; the rest, which
/// the samples measure only in combination with other parameters, as one
/// group.
pub fn unidentifiable_groups(
    model: &StageModel,
    names: &[String],
    samples: &[Sample],
) -> Vec<UnidentifiableGroup> {
    /// A periodic term's unidentifiable harmonics.
    struct Periodic {
        term: String,
        axis: Axis,
        period_um: f64,
        harmonics: Vec<u32>,
        names: Vec<String>,
    }
    let params = model.params();
    let mut periodic: Vec<Periodic> = Vec::new();
    let mut thermal: Vec<String> = Vec::new();
    let mut other: Vec<String> = Vec::new();
    for name in names {
        let Some((term_name, param)) = name.split_once('.') else {
            other.push(name.clone());
            continue;
        };
        let cfg = model
            .terms()
            .iter()
            .find(|t| t.name() == term_name)
            .and_then(|t| t.to_config().ok());
        let period = cfg
            .as_ref()
            .and_then(|c| c.get("period_um"))
            .and_then(|v| v.as_float());
        let axis = cfg
            .as_ref()
            .and_then(|c| c.get("axis"))
            .and_then(|v| v.as_str())
            .and_then(|a| match a {
                "x" => Some(Axis::X),
                "y" => Some(Axis::Y),
                _ => None,
            });
        let unit = params
            .iter()
            .find(|p| &p.full_name == name)
            .map(|p| p.info.unit);
        match (period, axis, harmonic(param)) {
            (Some(period_um), Some(axis), Some(k)) if period_um > 0.0 => {
                match periodic.iter_mut().find(|g| g.term == term_name) {
                    Some(g) => {
                        if !g.harmonics.contains(&k) {
                            g.harmonics.push(k);
                        }
                        g.names.push(name.clone());
                    }
                    None => periodic.push(Periodic {
                        term: term_name.to_owned(),
                        axis,
                        period_um,
                        harmonics: vec![k],
                        names: vec![name.clone()],
                    }),
                }
            }
            _ if unit.is_some_and(|u| u.contains("°C")) => thermal.push(name.clone()),
            _ => other.push(name.clone()),
        }
    }
    let mut out = Vec::new();
    for mut g in periodic {
        g.harmonics.sort_unstable();
        let pos = positions(samples, g.axis);
        let span = match (pos.first(), pos.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let step = sampling_spacing_um(&pos);
        let advice = periodic_advice(&g.term, g.axis, g.period_um, &g.harmonics, step, span);
        out.push(UnidentifiableGroup {
            term: Some(g.term),
            params: g.names,
            advice,
        });
    }
    if !thermal.is_empty() {
        out.push(UnidentifiableGroup {
            term: None,
            advice: format!(
                "{} temperature coefficient{}: the log's temperature does not change enough to tell a coefficient from an offset; a log over a temperature change identifies them",
                thermal.len(),
                if thermal.len() == 1 { "" } else { "s" }
            ),
            params: thermal,
        });
    }
    if !other.is_empty() {
        out.push(UnidentifiableGroup {
            term: None,
            advice: format!(
                "{}: the log's points move under {} as under a combination of other parameters, so only that combination is measured; kept at the template's values (`micropos diagnose LOG` names each combination; scans at other positions of the held axis, or a grid log, separate many of them)",
                and_list(&other),
                if other.len() == 1 { "it" } else { "each" }
            ),
            params: other,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::MotionState;

    fn scan(step_um: f64, n: usize) -> Vec<Sample> {
        let mut v = Vec::new();
        for i in 0..n {
            let p = 7000.0 + step_um * i as f64;
            for state in [
                MotionState::at_rest(p, 7100.0),
                MotionState::at_rest(7000.0, 7100.0 + step_um * i as f64),
            ] {
                v.push(Sample {
                    state,
                    measured_x_um: 0.0,
                    measured_y_um: 0.0,
                });
            }
        }
        v
    }

    #[test]
    fn the_harmonic_number_of_a_periodic_parameter() {
        assert_eq!(harmonic("forward_sin_3_um"), Some(3));
        assert_eq!(harmonic("cos_1_urad"), Some(1));
        assert_eq!(harmonic("slope_urad_per_mm"), None);
        assert_eq!(harmonic("ppm"), None);
    }

    /// Issue 33: 33 names, one line each, no advice. On a 100 µm step the
    /// default model's 400 µm screw harmonics 2 and 3 are beyond Nyquist
    /// and 3 folds onto 1: the advice says so with the step they need,
    /// computed from the samples (an 80 µm step resolves harmonic 2, not
    /// 3: 33 µm for it).
    #[test]
    fn periodic_terms_get_the_step_their_harmonics_need() {
        let model = StageModel::paper_default().unwrap();
        let names: Vec<String> = [
            "x_cyclic.forward_sin_1_um",
            "x_cyclic.forward_cos_1_um",
            "x_cyclic.forward_sin_2_um",
            "x_cyclic.forward_sin_3_um",
            "x_cyclic.forward_cos_3_um",
            "x_to_y_coupling.forward_sin_2_um",
            "squareness.angle_urad",
            "origin.y_um",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let g = unidentifiable_groups(&model, &names, &scan(100.0, 11));
        assert_eq!(g.len(), 3, "{g:#?}");
        assert_eq!(g[0].term.as_deref(), Some("x_cyclic"));
        assert_eq!(g[0].params.len(), 5);
        let a = &g[0].advice;
        assert!(
            a.contains("a step of 100 µm along x cannot resolve the 400 µm period's harmonics 2 and 3 (periods 200 µm and 133 µm")
                && a.contains("; harmonic 1 (harmonic 3 folds onto it at this step) is lost with them")
                && a.contains("Sample x at ≤ 133 µm / 4 = 33.3 µm"),
            "{a}"
        );
        assert!(
            g[1].advice.contains("Sample x at ≤ 200 µm / 4 = 50.0 µm"),
            "{}",
            g[1].advice
        );
        assert_eq!(g[2].term, None);
        assert_eq!(g[2].params, ["squareness.angle_urad", "origin.y_um"]);
        assert!(g[2].advice.contains("diagnose"), "{}", g[2].advice);

        // The numbers come from the samples' step, not from a text.
        let g = unidentifiable_groups(&model, &names[3..5], &scan(80.0, 13));
        assert!(
            g[0].advice.contains("a step of 80.0 µm along x cannot resolve the 400 µm period's harmonic 3 (period 133 µm")
                && g[0].advice.contains("= 33.3 µm"),
            "{}",
            g[0].advice
        );
    }
}
