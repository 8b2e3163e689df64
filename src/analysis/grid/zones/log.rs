//! The combined map as a measurement log: one record per measured node,
//! so `diagnose`, `tables build` and everything else that reads a grid log
//! read it, and the metadata says which zones it came from and how each
//! was corrected.

use std::fmt::Write as _;

use crate::analysis::diagnose::{MEASURED_AXES_KEY, TIME_SOURCE_KEY};
use crate::charact::log::{
    Columns, LogError, LogWriter, Metadata, Record, SyncPolicy, FORMAT_ID, FORMAT_KEY,
};

use super::{Estimate, ZoneCombination, ZoneSetup};

/// A value with its σ at the resolution the σ allows.
fn est(e: &Estimate, unit: &str) -> String {
    let d = if e.sigma > 0.0 && e.sigma.is_finite() {
        (1.0 - e.sigma.log10().floor()).clamp(0.0, 6.0) as usize
    } else {
        4
    };
    format!("{:+.d$}±{:.d$}{unit}", e.value, e.sigma)
}

/// A name as a metadata value: no control characters, trimmed.
fn clean(s: &str) -> String {
    let s: String = s.chars().filter(|c| !c.is_control()).collect();
    s.trim().to_owned()
}

/// One zone's set-up as a metadata value.
fn setup_text(s: &ZoneSetup) -> String {
    let mut t = format!("name={}", clean(&s.name));
    if s.reference {
        t.push_str("; reference (its set-up is the map's frame)");
    }
    let _ = write!(
        t,
        "; centre_um=({:.3}, {:.3}); offset_x={}; offset_y={}; dex_dy={}; dey_dx={}; \
         overlap_nodes={}; rms_um=({:.4}, {:.4})",
        s.centre_um[0],
        s.centre_um[1],
        est(&s.offset_x_um, "um"),
        est(&s.offset_y_um, "um"),
        est(&s.dex_dy_urad, "urad"),
        est(&s.dey_dx_urad, "urad"),
        s.overlap_nodes,
        s.rms_um[0],
        s.rms_um[1],
    );
    t
}

/// The metadata of the combined log; `extra` is added after it (a key
/// of it replaces the same key here).
fn metadata(comb: &ZoneCombination, extra: &Metadata) -> Metadata {
    let mut md = Metadata::new();
    md.insert(FORMAT_KEY, FORMAT_ID);
    md.insert(
        "combined_by",
        "micropos combine: overlapping grid zones, set-ups fitted on the overlaps",
    );
    md.insert(MEASURED_AXES_KEY, "x,y");
    md.insert(
        TIME_SOURCE_KEY,
        "synthetic: node order, 1 s per node (a combined map has no times)",
    );
    md.insert("error_sign", "target - meas (micropos)");
    md.insert(
        "layout",
        "one segment 'grid', one record per node: the mean of the zones' readings there, \
         each corrected by its fitted set-up",
    );
    let names: Vec<String> = comb.setups.iter().map(|s| clean(&s.name)).collect();
    md.insert("zones", names.join(" ; "));
    if let Some(r) = names.get(comb.reference) {
        md.insert(
            "zone_frame",
            format!("the set-up of zone {r}: every other zone's set-up is relative to it"),
        );
    }
    md.insert(
        "zone_model",
        "s = (offset_x + dex_dy*(y - centre_y), offset_y + dey_dx*(x - centre_x)), \
         e = meas - target, slopes in urad, 1 sigma",
    );
    for (k, s) in comb.setups.iter().enumerate() {
        md.insert(format!("zone_{}", k + 1), setup_text(s));
    }
    md.insert(
        "zone_noise_um",
        format!(
            "x {:.4}, y {:.4} per reading, from the overlap residuals (dof {:.0}, {:.0})",
            comb.noise_um[0], comb.noise_um[1], comb.dof[0], comb.dof[1]
        ),
    );
    for (k, v) in extra.iter() {
        md.insert(k, v);
    }
    md
}

/// The combined map as the bytes of a measurement log (module docs):
/// target = command = the node, meas = node + error, segment `grid`.
pub fn combined_log(comb: &ZoneCombination, extra: &Metadata) -> Result<Vec<u8>, LogError> {
    let md = metadata(comb, extra);
    let mut w = LogWriter::create(
        Vec::new(),
        &md,
        Columns::new(false, Vec::new())?,
        SyncPolicy::FlushOnly,
    )?;
    let map = &comb.map;
    let mut i = 0usize;
    for (iy, &y) in map.ys_um.iter().enumerate() {
        for (ix, &x) in map.xs_um.iter().enumerate() {
            let Some(cell) = map.cell(ix, iy) else {
                continue;
            };
            w.append(&Record {
                t_s: i as f64,
                segment: "grid".into(),
                cycle: 1,
                x_target_um: x,
                y_target_um: y,
                x_cmd_um: x,
                y_cmd_um: y,
                x_meas_um: x + cell.e_um[0],
                y_meas_um: y + cell.e_um[1],
                temp_c: None,
                theta_urad: None,
                extra: Vec::new(),
            })?;
            i += 1;
        }
    }
    Ok(w.into_inner())
}
