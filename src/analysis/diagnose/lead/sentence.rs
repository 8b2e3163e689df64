//! The lead check's statement for a metrologist: the corrected lead with
//! its standard error and held-out test, the lead kept and why, or what
//! the log cannot tell with the scan that would.

use super::{LeadCheck, LeadTest, LeadVerdict};

/// A lead for people: one decimal, none when whole.
pub(super) fn um(v: f64) -> String {
    let s = format!("{v:.1}");
    s.strip_suffix(".0").map(str::to_string).unwrap_or(s)
}

/// The check's statement (see [`LeadCheck::sentence`]).
pub(super) fn sentence(check: &LeadCheck) -> String {
    match (check.verdict, &check.candidate) {
        (LeadVerdict::Corrected, Some(t)) => corrected_sentence(check, t),
        (LeadVerdict::Kept, Some(t)) => kept_sentence(check, t),
        _ => not_checked_sentence(check),
    }
}

/// The corrected lead, its standard error to two significant digits, the
/// held-out test that adopted it and the leads scanned: the figures a
/// reader needs to weigh the correction.
fn corrected_sentence(check: &LeadCheck, t: &LeadTest) -> String {
    let [lo, hi] = check.scanned_um.unwrap_or([t.lead_um; 2]);
    // Two significant digits of σ, and the lead to the same place.
    let places = check
        .std_error_um
        .filter(|s| *s > 0.0)
        .map_or(1, |s| (1.0 - s.log10().floor()).clamp(1.0, 4.0) as usize);
    let se = check
        .std_error_um
        .map(|s| format!(" ± {s:.places$}"))
        .unwrap_or_default();
    let mut s = format!(
        "this stage's screw lead (the period of its cyclic error) `{}.period_um` is {:.places$}{se} µm, the model says {} µm; held out rms {:.4} → {:.4} µm (z {:.1}; leads {}–{} µm scanned)",
        check.term,
        check.lead_um,
        um(check.model_lead_um),
        t.heldout_rms_model_um,
        t.heldout_rms_um,
        t.z,
        um(lo),
        um(hi)
    );
    if !check.followers.is_empty() {
        s.push_str(&format!(
            "; the cross coupling of the same screw ({}) takes the same lead",
            check.followers.join(", ")
        ));
    }
    s
}

/// Why the model's lead stays: no candidate beats it held out, or one
/// does but the model's lead still adds to it (a periodic error beside
/// the screw's, the search's to name).
fn kept_sentence(check: &LeadCheck, t: &LeadTest) -> String {
    let [lo, hi] = check.scanned_um.unwrap_or([t.lead_um; 2]);
    let head = format!(
        "{} (the screw lead, {} µm in the model) is checked",
        check.term,
        um(check.model_lead_um)
    );
    if t.beats_model && t.model_adds {
        return format!(
            "{head}: a lead of {:.1} µm predicts held-out {} better ({:.4} → {:.4} µm, z {:.1}), but the model's lead still adds to it (z {:.1}): the stage has a periodic error besides its screw's, which the search judges",
            t.lead_um,
            check.axis,
            t.heldout_rms_model_um,
            t.heldout_rms_um,
            t.z,
            t.both_z.unwrap_or(f64::NAN)
        );
    }
    format!(
        "{head}: no lead between {} and {} µm predicts held-out {} better than the model's (the best, {:.1} µm: held out rms {:.4} → {:.4} µm, z {:+.1})",
        um(lo),
        um(hi),
        check.axis,
        t.lead_um,
        t.heldout_rms_model_um,
        t.heldout_rms_um,
        t.z
    )
}

/// Why the log cannot tell the lead (its span, its spacing, with the
/// numbers), what becomes of the harmonics, and the scan that would tell
/// it: a metrologist reading "not checked" must learn what to measure.
fn not_checked_sentence(check: &LeadCheck) -> String {
    let head = format!(
        "{} (the screw lead, {} µm in the model) is not checked",
        check.term,
        um(check.model_lead_um)
    );
    let needs = format!(
        "a scan over ≥ {} µm at ≤ {} µm steps resolves them",
        um(check.needs_span_um),
        um(check.needs_step_um)
    );
    let Some(spacing) = check.spacing_um else {
        return format!(
            "{head}: the log does not scan {}; its harmonics are held at the model's values; {needs}",
            check.axis
        );
    };
    format!(
        "{head}: {}; {}; {needs}",
        why_not_checked(check, spacing),
        held_harmonics(check, spacing)
    )
}

/// What the log lacks to tell the lead: its span, its spacing or both.
fn why_not_checked(check: &LeadCheck, spacing_um: f64) -> String {
    let axis = check.axis;
    let mut why = Vec::new();
    if check.span_um < check.needs_span_um {
        why.push(format!(
            "the log spans {} µm of {axis}, less than two leads ({} µm)",
            um(check.span_um),
            um(check.needs_span_um)
        ));
    }
    if spacing_um > check.needs_step_um {
        why.push(format!(
            "its {axis} positions are {} µm apart, more than a quarter lead ({} µm)",
            um(spacing_um),
            um(check.needs_step_um)
        ));
    }
    why.join(" and ")
}

/// What becomes of the harmonics the log cannot check: aliased; held,
/// with what they contribute at the log's points (a claim of the model
/// the log can neither confirm nor correct), over fewer than two leads;
/// else fitted at the model's lead.
fn held_harmonics(check: &LeadCheck, spacing_um: f64) -> String {
    if check.model_lead_um < 2.0 * spacing_um {
        return "its harmonics are aliased and held at the model's values".into();
    }
    let held = check
        .held_contribution_rms_um
        .map(|h| {
            format!(
                " ({h:.3} µm rms at the log's points, a claim the log can neither confirm nor correct)"
            )
        })
        .unwrap_or_default();
    if check.span_um < check.needs_span_um {
        format!("its harmonics cannot be told from a bow of the travel and are held at the model's values{held}")
    } else {
        "its harmonics are fitted at the model's lead, taken as given".into()
    }
}
