//! The combination as text: the set-up table a lab reads before it uses
//! the combined map (is every zone consistent with the others to the
//! noise?), then the map.

use std::fmt::Write as _;

use super::{Estimate, ZoneCombination, ZoneSetup};

/// Digits after the point for uncertainty `sigma`: two significant digits.
fn decimals(sigma: f64) -> usize {
    if !(sigma.is_finite() && sigma > 0.0) {
        return 4;
    }
    (1.0 - sigma.log10().floor()).clamp(0.0, 6.0) as usize
}

/// `+1.234 ± 0.012`, or `0 (reference)`.
fn est(e: &Estimate, reference: bool) -> String {
    if reference {
        return "0".into();
    }
    let d = decimals(e.sigma);
    format!("{:+.d$} ± {:.d$}", e.value, e.sigma)
}

fn row(s: &ZoneSetup) -> String {
    let name = if s.reference {
        format!("{} (reference)", s.name)
    } else {
        s.name.clone()
    };
    format!(
        "{name:<24} {:>20} {:>20} {:>18} {:>18} {:>7} {:>8.4} {:>8.4}",
        est(&s.offset_x_um, s.reference),
        est(&s.offset_y_um, s.reference),
        est(&s.dex_dy_urad, s.reference),
        est(&s.dey_dx_urad, s.reference),
        s.overlap_nodes,
        s.rms_um[0],
        s.rms_um[1],
    )
}

/// Median and largest of the nodes' σ per component, µm.
fn sigma_summary(comb: &ZoneCombination) -> [(f64, f64); 2] {
    std::array::from_fn(|c| {
        let mut v: Vec<f64> = comb.node_sigma_um.iter().flatten().map(|s| s[c]).collect();
        v.sort_by(f64::total_cmp);
        (
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN),
            v.last().copied().unwrap_or(f64::NAN),
        )
    })
}

/// Writes the set-up table and the combined map's summary.
pub fn write_text(out: &mut String, comb: &ZoneCombination) {
    let _ = writeln!(
        out,
        "set-ups relative to the reference zone's (e = meas − target; s = (ox + a·(y − yc), \
         oy + b·(x − xc)), offsets at each zone's centre; ± 1σ):"
    );
    let _ = writeln!(
        out,
        "{:<24} {:>20} {:>20} {:>18} {:>18} {:>7} {:>8} {:>8}",
        "zone",
        "ox µm",
        "oy µm",
        "a = d(ex)/dy µrad",
        "b = d(ey)/dx µrad",
        "overlap",
        "rms x µm",
        "rms y µm"
    );
    for s in &comb.setups {
        let _ = writeln!(out, "{}", row(s));
    }
    let _ = writeln!(
        out,
        "noise of one reading from the overlaps: x {:.4} µm, y {:.4} µm (dof {:.0}, {:.0}); an \
         overlap's rms is √2 × that when its zones agree to their noise",
        comb.noise_um[0], comb.noise_um[1], comb.dof[0], comb.dof[1]
    );
    let shared = comb.zones_per_node.iter().filter(|&&n| n > 1).count();
    let [sx, sy] = sigma_summary(comb);
    let _ = writeln!(
        out,
        "combined map: {} × {} nodes, {} measured ({shared} by more than one zone); node σ \
         median x {:.4} / y {:.4} µm, largest x {:.4} / y {:.4} µm",
        comb.map.nx(),
        comb.map.ny(),
        comb.map.filled(),
        sx.0,
        sy.0,
        sx.1,
        sy.1
    );
}
