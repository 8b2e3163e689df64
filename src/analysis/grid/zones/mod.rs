//! Several overlapping grid maps of one stage ("zones"), each taken with
//! its own instrument set-up, combined into one map.
//!
//! Why: a laser interferometer (or a camera's tie) reaches only part of a
//! large stage at one set-up, so the stage is mapped zone by zone and the
//! instrument is set up again between zones: its zero and its mirrors'
//! alignment change every time. The stage's error is the same in every
//! zone; the set-up is not. Where zones overlap, both read the same stage
//! at the same commanded positions, so their difference is the difference
//! of their set-ups alone, and the set-ups can be fitted there.
//!
//! **Model.** Zone `k` reads `e_k(x, y) = E(x, y) + s_k(x, y) + noise`
//! (`e = measured − target`, µm, as [`GridMap`]), with the set-up term
//!
//! ```text
//! s_k = ( ox_k + a_k·(y − yc_k),  oy_k + b_k·(x − xc_k) )      a, b in µrad (µm/m)
//! ```
//!
//! where `(xc_k, yc_k)` is the centre of zone `k`'s lattice (the midpoint
//! of its extent), so `ox_k`, `oy_k` are the set-up's offsets where the
//! zone's data are, not at a far-away origin (an offset at the stage's
//! origin would be mostly slope times distance, and as uncertain).
//! `a_k = d(ex)/dy` and `b_k = d(ey)/dx` are the cross slopes: the x
//! reading's mirror (long along y) turned by `−a_k` and the y reading's
//! mirror (long along x) turned by `b_k`. A rotation of the whole
//! instrument frame by `φ` counter-clockwise gives `a = −φ`, `b = +φ`
//! (the sign of [`super::Geometry::frame_rotation_urad`]); the two mirrors'
//! own misalignments make `a` and `b` independent, so both are fitted.
//! Scales (`d(ex)/dx`, `d(ey)/dy`) are not part of a set-up here: a
//! difference of scale between set-ups (a wrong air compensation) shows
//! as overlap residuals above the noise.
//!
//! **Reference.** One zone ([`ZoneOptions::reference`], default the first)
//! defines the frame: its set-up is taken as zero, and every other zone's
//! fitted set-up is *its set-up minus the reference's*, expressed at its own
//! centre. The combined map is the stage's error as the reference set-up
//! reads it (`E + s_ref`): no map can tell a set-up common to all zones
//! from the stage.
//!
//! **Fit** (`fit`, `overlap`). Every filled node of a zone that lies inside
//! another zone's lattice, with that zone's bilinear interpolation defined
//! there (its surrounding cells measured), gives, per component, one
//! equation `e_j(p) − e_k(p) = s_j(p) − s_k(p)`; bilinear interpolation
//! reproduces the set-up terms exactly (they are linear in x or in y), so
//! the only model error is the stage's own curvature between the other
//! zone's nodes, nil where the zones' nodes coincide (the usual case:
//! one plan's lattice, shifted by whole pitches). The two components are
//! fitted apart (linear least squares; `x`: the offsets `ox` and slopes
//! `a`; `y`: `oy`, `b`). Weights: a node that `m` zones measured gives
//! each of its `m(m−1)` ordered pairs the weight `1/(2m)`, which makes the
//! fit exactly the least squares of the joint model (one unknown stage
//! value per node) when the nodes coincide, so the noise estimated from the
//! weighted residuals (`Σ w·r² / (2·Σw − parameters)`) is the noise of one
//! reading and the parameters' σ are right. With interleaved nodes the
//! weights are an approximation (the other zone's value is interpolated:
//! its noise is shared by neighbouring equations, so the σ come out some
//! 15 % small in the tests) and the residuals carry the stage's curvature
//! between nodes, which raises the estimated noise and the σ with it.
//!
//! **Enough overlap.** Every zone must be linked to the reference through a
//! chain of overlaps ([`ZoneError::NotConnected`]), and its overlaps must
//! determine all four parameters: a slope `a` needs overlaps on at least
//! two rows (distinct y), `b` on two columns. A single shared line leaves
//! a slope free: that is an error naming the zone and the slope
//! ([`ZoneError::Undetermined`]), not a fit of fewer parameters, because a
//! map combined with an unfitted mirror slope is sheared between zones by
//! it, silently. The noise needs at least one degree of freedom beyond the
//! parameters ([`ZoneError::TooLittleOverlap`]).
//!
//! **Combination** (`merge`). The union lattice of the zones' node
//! positions (clustered within [`ZoneOptions::node_tol_um`]); each node
//! the mean of the corrected values `e_k − s_k` of the zones that measured
//! it, `None` where none did. Each node counts as one visit (as the log of
//! the combined map reads back: one record per node), and
//! [`ZoneCombination::zones_per_node`] says how many zones it averages.
//! [`ZoneCombination::node_sigma_um`] is each node's uncertainty: the
//! noise of the readings averaged and the fitted set-ups' uncertainty
//! carried to it (a slope's σ times the distance from the overlap that
//! fixed it, so the far side of a zone overlapped on a narrow strip is the
//! least certain part of the map).

mod fit;
mod log;
mod merge;
mod overlap;
#[cfg(test)]
mod tests;
mod text;

use serde::Serialize;

use super::GridMap;
use crate::charact::log::MAX_ABS_VALUE;

pub use log::combined_log;
pub use text::write_text;

/// A zone: its map and a name for messages and the combined log's
/// metadata (a file name, say).
#[derive(Debug, Clone, PartialEq)]
pub struct Zone {
    /// Name (a file name, say).
    pub name: String,
    /// The zone's map, as read from its log.
    pub map: GridMap,
}

/// How zones are combined (default: the first zone is the reference, the
/// node tolerance automatic).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ZoneOptions {
    /// Index of the zone whose set-up is the frame (default 0).
    pub reference: usize,
    /// Distance within which node positions of different zones are one
    /// node, µm; `None`: 1 % of the smallest node spacing of any zone,
    /// and never less than what [`GridMap::from_records`] tells apart.
    pub node_tol_um: Option<f64>,
}

/// Why zones cannot be combined.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ZoneError {
    /// Fewer than two zones.
    #[error("{zones} zone(s): combining needs at least 2")]
    TooFewZones {
        /// Zones given.
        zones: usize,
    },
    /// The reference index is out of range.
    #[error("reference zone {reference} does not exist ({zones} zones)")]
    BadReference {
        /// The index asked for.
        reference: usize,
        /// Zones given.
        zones: usize,
    },
    /// A zone's map is not a lattice with finite values.
    #[error("zone {zone}: {reason}")]
    Malformed {
        /// The zone's name.
        zone: String,
        /// What is wrong.
        reason: String,
    },
    /// The node tolerance is negative or not finite.
    #[error("node tolerance {tol_um} µm: must be finite and ≥ 0")]
    BadTolerance {
        /// The tolerance given.
        tol_um: f64,
    },
    /// A zone shares no overlap, directly or through other zones, with
    /// the reference zone.
    #[error(
        "zone {zone} does not overlap the reference zone {reference}, directly or through \
         other zones: no node of it lies inside another zone's measured lattice"
    )]
    NotConnected {
        /// The zone's name.
        zone: String,
        /// The reference zone's name.
        reference: String,
    },
    /// A zone's overlaps do not determine one of its set-up parameters.
    #[error(
        "zone {zone}: its {parameter} is not determined by its overlaps with other zones \
         (they need {need}; a single shared line is not enough)"
    )]
    Undetermined {
        /// The zone's name.
        zone: String,
        /// The parameter (`d(ex)/dy slope`, …).
        parameter: &'static str,
        /// What the overlap lacks.
        need: &'static str,
    },
    /// The least squares did not converge (it cannot on finite, bounded
    /// input; kept so that nothing panics).
    #[error("the least squares of the {component} component did not converge")]
    Numeric {
        /// `x` or `y`.
        component: &'static str,
    },
    /// The overlaps have no degree of freedom left for the noise.
    #[error(
        "too little overlap: {equations:.1} independent overlap differences of the {component} \
         component for {parameters} set-up parameters (at least one more is needed to \
         estimate the noise)"
    )]
    TooLittleOverlap {
        /// `x` or `y`.
        component: &'static str,
        /// Independent differences (2 × the summed weights).
        equations: f64,
        /// Parameters fitted for that component.
        parameters: usize,
    },
}

/// A fitted value with its standard uncertainty (1 σ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Estimate {
    /// Value.
    pub value: f64,
    /// Standard uncertainty from the least squares (noise from the
    /// overlap residuals); 0 for the reference zone.
    pub sigma: f64,
}

/// One zone's fitted set-up, relative to the reference zone's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ZoneSetup {
    /// The zone's name.
    pub name: String,
    /// Whether this is the reference zone (all parameters 0 ± 0).
    pub reference: bool,
    /// Centre of the zone's lattice `[x, y]` (midpoint of its extent),
    /// where the offsets apply, µm.
    pub centre_um: [f64; 2],
    /// `ox`: offset of the x reading at the centre, µm.
    pub offset_x_um: Estimate,
    /// `oy`: offset of the y reading at the centre, µm.
    pub offset_y_um: Estimate,
    /// `a = d(ex)/dy` of the set-up, µrad.
    pub dex_dy_urad: Estimate,
    /// `b = d(ey)/dx` of the set-up, µrad.
    pub dey_dx_urad: Estimate,
    /// The zone's filled nodes that lie inside another zone's lattice
    /// (where that zone could be interpolated).
    pub overlap_nodes: usize,
    /// RMS of the overlap differences the zone takes part in, after the
    /// fit, per component `[x, y]`, µm: `√2` times the reading noise when
    /// the zones agree to their noise (a difference of two readings).
    pub rms_um: [f64; 2],
}

impl ZoneSetup {
    /// The set-up term `s(x, y)` `[x, y]`, µm: what this zone reads more
    /// than the reference zone would at `(x, y)`.
    pub fn at(&self, x_um: f64, y_um: f64) -> [f64; 2] {
        [
            self.offset_x_um.value + 1e-6 * self.dex_dy_urad.value * (y_um - self.centre_um[1]),
            self.offset_y_um.value + 1e-6 * self.dey_dx_urad.value * (x_um - self.centre_um[0]),
        ]
    }
}

/// Zones combined: the fitted set-ups and the one map.
#[derive(Debug, Clone, PartialEq)]
pub struct ZoneCombination {
    /// Per zone, in the order given.
    pub setups: Vec<ZoneSetup>,
    /// Index of the reference zone.
    pub reference: usize,
    /// Noise of one reading per component `[x, y]`, µm, from the weighted
    /// overlap residuals.
    pub noise_um: [f64; 2],
    /// Degrees of freedom of that noise per component.
    pub dof: [f64; 2],
    /// The combined map, in the reference zone's set-up.
    pub map: GridMap,
    /// Readings averaged at each node of the map, row-major (0: none):
    /// the zones that measured it (unless a node tolerance wider than a
    /// zone's own spacing merges nodes of one zone).
    pub zones_per_node: Vec<usize>,
    /// Standard uncertainty of each node of the map `[x, y]`, row-major,
    /// µm (`None` where no zone measured): the noise of the readings
    /// averaged there and the fitted set-ups' uncertainty carried to the
    /// node, which grows with the distance from the overlaps.
    pub node_sigma_um: Vec<Option<[f64; 2]>>,
    /// Node tolerance used, µm.
    pub node_tol_um: f64,
}

/// Fits the zones' set-ups on their overlaps and combines them (module
/// docs). Never panics; every refusal is a [`ZoneError`].
pub fn combine_zones(zones: &[Zone], opts: &ZoneOptions) -> Result<ZoneCombination, ZoneError> {
    validate(zones, opts)?;
    let tol = node_tol(zones, opts)?;
    let maps: Vec<&GridMap> = zones.iter().map(|z| &z.map).collect();
    let eqs = overlap::equations(&maps, tol);
    let centres: Vec<[f64; 2]> = maps.iter().map(|m| centre(m)).collect();
    let names: Vec<&str> = zones.iter().map(|z| z.name.as_str()).collect();
    fit::connected(&eqs.list, zones.len(), opts.reference).map_err(|k| {
        ZoneError::NotConnected {
            zone: names[k].to_owned(),
            reference: names[opts.reference].to_owned(),
        }
    })?;
    let problem = fit::Problem {
        eqs: &eqs.list,
        centres: &centres,
        reference: opts.reference,
        names: &names,
    };
    let fits = [problem.solve(0)?, problem.solve(1)?];
    let setups = (0..zones.len())
        .map(|k| setup(k, &names, &centres, &fits, &eqs, opts.reference))
        .collect::<Vec<_>>();
    let (map, zones_per_node) = merge::combine(&maps, &setups, tol);
    let node_sigma_um = merge::sigmas(&map, &maps, &centres, &fits, tol);
    Ok(ZoneCombination {
        setups,
        reference: opts.reference,
        noise_um: [fits[0].noise_um, fits[1].noise_um],
        dof: [fits[0].dof, fits[1].dof],
        map,
        zones_per_node,
        node_sigma_um,
        node_tol_um: tol,
    })
}

/// Zone `k`'s set-up from the two components' fits.
fn setup(
    k: usize,
    names: &[&str],
    centres: &[[f64; 2]],
    fits: &[fit::ComponentFit; 2],
    eqs: &overlap::Equations,
    reference: usize,
) -> ZoneSetup {
    let est = |c: usize, p: usize| {
        let (value, sigma) = fits[c].param(k, p);
        Estimate { value, sigma }
    };
    ZoneSetup {
        name: names[k].to_owned(),
        reference: k == reference,
        centre_um: centres[k],
        offset_x_um: est(0, 0),
        offset_y_um: est(1, 0),
        dex_dy_urad: est(0, 1),
        dey_dx_urad: est(1, 1),
        overlap_nodes: eqs.overlap_nodes[k],
        rms_um: [fits[0].zone_rms(k), fits[1].zone_rms(k)],
    }
}

/// Midpoint of a map's extent `[x, y]`, µm.
fn centre(map: &GridMap) -> [f64; 2] {
    let mid = |v: &[f64]| match (v.first(), v.last()) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        _ => 0.0,
    };
    [mid(&map.xs_um), mid(&map.ys_um)]
}

/// Refuses what the fit cannot read: too few zones, a bad reference, a
/// map that is not a finite, ascending lattice with a measured node.
fn validate(zones: &[Zone], opts: &ZoneOptions) -> Result<(), ZoneError> {
    if zones.len() < 2 {
        return Err(ZoneError::TooFewZones { zones: zones.len() });
    }
    if opts.reference >= zones.len() {
        return Err(ZoneError::BadReference {
            reference: opts.reference,
            zones: zones.len(),
        });
    }
    for z in zones {
        lattice_problem(&z.map).map_or(Ok(()), |reason| {
            Err(ZoneError::Malformed {
                zone: z.name.clone(),
                reason,
            })
        })?;
    }
    Ok(())
}

/// What makes a map unusable as a zone, if anything.
fn lattice_problem(m: &GridMap) -> Option<String> {
    let ascending =
        |v: &[f64]| v.iter().all(|x| x.is_finite()) && v.windows(2).all(|w| w[0] < w[1]);
    if m.xs_um.is_empty() || m.ys_um.is_empty() {
        return Some("no node positions".into());
    }
    if !ascending(&m.xs_um) || !ascending(&m.ys_um) {
        return Some("node positions not finite and strictly ascending".into());
    }
    if m.cells.len() != m.xs_um.len().saturating_mul(m.ys_um.len()) {
        return Some(format!(
            "{} cells for {} × {} nodes",
            m.cells.len(),
            m.xs_um.len(),
            m.ys_um.len()
        ));
    }
    if m.cells
        .iter()
        .flatten()
        .any(|c| !c.e_um.iter().all(|v| v.is_finite()))
    {
        return Some("a measured node has a non-finite error".into());
    }
    let inside = |v: &f64| v.abs() <= MAX_ABS_VALUE;
    let values = m.cells.iter().flatten().flat_map(|c| c.e_um.iter());
    if !(m.xs_um.iter().chain(&m.ys_um).chain(values).all(inside)) {
        return Some(format!(
            "a position or error beyond ±{MAX_ABS_VALUE:e} µm (the log format's bound)"
        ));
    }
    if m.filled() == 0 {
        return Some("no measured node".into());
    }
    None
}

/// The node tolerance: the option's, or 1 % of the smallest node spacing
/// of any zone, at least [`GridMap::from_records`]'s own (so the combined
/// map's log reads back to the same lattice).
fn node_tol(zones: &[Zone], opts: &ZoneOptions) -> Result<f64, ZoneError> {
    if let Some(t) = opts.node_tol_um {
        if !(t.is_finite() && t >= 0.0) {
            return Err(ZoneError::BadTolerance { tol_um: t });
        }
        return Ok(t);
    }
    let axes = || zones.iter().flat_map(|z| [&z.map.xs_um, &z.map.ys_um]);
    let spacing = axes()
        .flat_map(|v| v.windows(2).map(|w| w[1] - w[0]))
        .fold(f64::INFINITY, f64::min);
    let (lo, hi) = axes()
        .flatten()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let reader = (1e-6 * (hi - lo)).max(1e-3);
    Ok(if spacing.is_finite() {
        (0.01 * spacing).max(reader)
    } else {
        reader
    })
}
