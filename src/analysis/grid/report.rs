//! The text of a [`GridReport`]: what the map measures first, then what
//! the separable model leaves, then what nothing here explains.
//!
//! Why a file of its own: presentation only. Every number is printed to
//! the resolution its σ allows and with its unit and sign convention.

use std::fmt::Write as _;

use super::{GridReport, Slope};

/// Digits after the point for a value of uncertainty `sigma`: two
/// significant digits of σ.
fn decimals(sigma: f64) -> usize {
    if !(sigma.is_finite() && sigma > 0.0) {
        return 2;
    }
    (1.0 - sigma.log10().floor()).clamp(0.0, 6.0) as usize
}

/// `+9.6 ± 0.4` at the resolution σ allows, or why it is not determined.
fn slope(s: &Slope, unit: &str) -> String {
    if !s.value.is_finite() || !s.sigma.is_finite() {
        return "not determined by this map (too few lines to fit a plane)".into();
    }
    let d = decimals(s.sigma);
    format!("{:+.d$} ± {:.d$} {unit}", s.value, s.sigma)
}

fn um(v: f64) -> String {
    if !v.is_finite() {
        return "n/a".into();
    }
    let d = if v.abs() >= 1.0 { 2 } else { 3 };
    format!("{v:.d$} µm")
}

/// Writes the grid section of a diagnosis report.
pub fn write_text(out: &mut String, r: &GridReport) {
    let g = &r.geometry;
    let _ = writeln!(
        out,
        "2-D grid map: {} × {} positions ({} cells visited, {} visit(s) per cell), pitch {:.0} × {:.0} µm, x {:.0}…{:.0} µm, y {:.0}…{:.0} µm",
        r.columns,
        r.rows,
        r.cells,
        r.visits_per_cell,
        r.pitch_um[0],
        r.pitch_um[1],
        r.x_range_um[0],
        r.x_range_um[1],
        r.y_range_um[0],
        r.y_range_um[1]
    );
    let _ = writeln!(
        out,
        "  errors e = measured − target; slopes in µm/m (ppm, µrad); σ: the larger of least squares and a jackknife over whole lines"
    );
    let _ = writeln!(
        out,
        "  geometry in the stage's frame (independent of how the instrument was aligned):"
    );
    let _ = writeln!(
        out,
        "    scale x (d(ex)/dx): {}",
        slope(&g.scale_x_ppm, "ppm")
    );
    let _ = writeln!(
        out,
        "    scale y (d(ey)/dy): {}",
        slope(&g.scale_y_ppm, "ppm")
    );
    let _ = writeln!(
        out,
        "    out-of-squareness (d(ex)/dy + d(ey)/dx): {}  (positive: +Y leans towards +X, the axes' angle is less than 90° by this)",
        slope(&g.out_of_squareness_urad, "µrad")
    );
    let _ = writeln!(
        out,
        "  the instrument's frame (a set-up nuisance, not the stage): the stage's x axis at {} from the instrument's x (d(ey)/dx), d(ex)/dy {} as measured",
        slope(&g.frame_rotation_urad, "µrad"),
        slope(&g.dex_dy_instrument_urad, "µrad")
    );
    if let Some(rv) = &r.reversal {
        let _ = writeln!(
            out,
            "  measured both ways: reversal e(from above) − e(from below) over {} cells: x mean {:+.3} µm (spread {}, largest |{}|), y mean {:+.3} µm (spread {}, largest |{}|); the maps here are of the arrivals from below",
            rv.cells,
            rv.mean_um[0],
            um(rv.spread_um[0]),
            um(rv.max_abs_um[0]),
            rv.mean_um[1],
            um(rv.spread_um[1]),
            um(rv.max_abs_um[1])
        );
    }
    for (c, n) in r.noise.iter().enumerate() {
        let comp = if c == 0 { "x" } else { "y" };
        let along = |v: Option<f64>| v.map_or_else(|| "n/a".into(), um);
        let _ = writeln!(
            out,
            "  noise floor {comp}: {} per cell (from {}; second differences along x {}, along y {}{})",
            um(n.cell_sigma_um),
            n.source,
            along(n.along_x_um),
            along(n.along_y_um),
            n.replicate_um
                .map_or_else(String::new, |v| format!(", one visit's scatter {}", um(v)))
        );
    }
    for m in &r.components {
        let c = &m.component;
        let _ = writeln!(
            out,
            "  {c}: {} rms beyond the plane; the separable f(x) + g(y) leaves {} (the joint x–y part)",
            um(m.plane_rms_um),
            um(m.separable_rms_um)
        );
        for f in &m.folds {
            let _ = writeln!(
                out,
                "    held out ({}, {} cells): plane {}, separable {}, 2-D map {} (noise alone would leave {})",
                f.scheme,
                f.cells,
                um(f.plane_um),
                um(f.separable_um),
                um(f.map_um),
                um(f.noise_expected_um)
            );
        }
        match &m.non_separable {
            Some(ns) => {
                let _ = writeln!(
                    out,
                    "    FINDING: a non-separable error in {c}: {} rms net of noise (largest {:+.3} µm at x {:.0}, y {:.0} µm); no f(x) + g(y) holds it. A 2-D table predicts held-out cells to {} against {} (−{:.0} %, paired z {:.1})",
                    um(ns.rms_um),
                    ns.peak_um,
                    ns.peak_at_um[0],
                    ns.peak_at_um[1],
                    um(ns.heldout_map_um),
                    um(ns.heldout_separable_um),
                    ns.gain_pct,
                    ns.z
                );
                let (ax, ay) = (ns.slope_along_x_urad, ns.slope_along_y_urad);
                let _ = writeln!(
                    out,
                    "      its shape (as measured): the slope of e{c} along x runs over {:+.1}…{:+.1} µrad from row to row, along y over {:+.1}…{:+.1} µrad from column to column (a slope that changes across the other axis is a twist, or a guide bent differently along it)",
                    ax[0], ax[1], ay[0], ay[1]
                );
            }
            None => {
                let _ = writeln!(
                    out,
                    "    separable: a 2-D term does not predict held-out cells better (paired z {:.1})",
                    m.z
                );
            }
        }
        if let Some(u) = &m.unexplained {
            let _ = writeln!(
                out,
                "    UNEXPLAINED: held out {} against {} that the noise floor allows: {} rms of systematic error in {c} that nothing here predicts (finer than the {:.0} µm lattice, or noise larger than the neighbours show)",
                um(u.heldout_um),
                um(u.expected_um),
                um(u.excess_um),
                r.pitch_um[0].min(r.pitch_um[1])
            );
        }
    }
}
