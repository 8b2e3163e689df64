//! `tables build`: from a characterization log in the data directory, the
//! paper's lookup tables (`f_xx … b_yy`, `δx(y)`) and a model table (the
//! stage model fitted to the same scans), or from a grid log a 2-D map
//! (`crate::comp::grid`), written as compensation files
//! (`crate::comp::file`) next to the log and loaded, ready for `tables
//! activate` or for the validation modes `table` and `model`.
//!
//! Why a request and not a job: building takes seconds (the model fit
//! dominates) and moves nothing, so it runs on a blocking thread and the
//! reply carries the result.
//!
//! The daemon's scan log names its passes `scan_x_fwd`, `scan_x_bwd`, …
//! (see [`crate::charact::plan`]); the builders read one segment per axis with the
//! direction inferred from the command order. So the passes are merged
//! back into `scan_x` / `scan_y` in log order, and a record whose command
//! equals the previous one (the turn point of a pass, measured twice without
//! a move) is dropped: it adds no arrival and its direction cannot be told
//! from the commands.
//!
//! The vision → stage frame the log's `meas` columns were mapped with is
//! read from the log's metadata (`vision_frame_*`, written by the
//! characterization's own tie, see [`super::tie`]) and recorded in both
//! files, so closed loop can map fresh frames the same way.

use super::super::protocol::{ErrorCode, ProtoError, TablesBuildParams};
use super::super::rig::Rig;
use crate::analysis::diagnose::{diagnose, DiagnoseOptions};
use crate::analysis::drift::{correct_log_drift, LOG_DRIFT_METHOD};
use crate::analysis::grid::GridMap;
use crate::charact::log::{self, Metadata, Record};
use crate::charact::scan::{SEGMENT_MOVES, SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
use crate::comp::model_comp::{compensation_template_for, ModelBuildOptions};
use crate::comp::table::{CompTable, TableBuildOptions};
use crate::comp::yaw::YawTables;
use crate::comp::{
    fnv1a64_hex, CompFile, GridArrival, GridTable, ModelCompensator, SourceInfo, VisionFrame,
};
use crate::model::StageModel;
use serde_json::{json, Value};
use std::path::Path;

/// The scan records of a daemon log as the builders expect them: passes
/// merged per axis, zero-motion repeats dropped (see the module docs).
/// Records of other segments (and of foreign writers already using
/// `scan_x` / `scan_y`) pass through unchanged.
pub fn merged_scan_records(records: &[Record]) -> Vec<Record> {
    let mut out: Vec<Record> = Vec::with_capacity(records.len());
    let mut last: [Option<(f64, f64)>; 2] = [None, None];
    for r in records {
        let (axis, seg) = match r.segment.as_str() {
            "scan_x_fwd" | "scan_x_bwd" | SEGMENT_SCAN_X => (0, SEGMENT_SCAN_X),
            "scan_y_fwd" | "scan_y_bwd" | SEGMENT_SCAN_Y => (1, SEGMENT_SCAN_Y),
            _ => {
                out.push(r.clone());
                continue;
            }
        };
        let cmd = (r.x_cmd_um, r.y_cmd_um);
        if last[axis] == Some(cmd) {
            continue;
        }
        last[axis] = Some(cmd);
        let mut m = r.clone();
        m.segment = seg.to_owned();
        out.push(m);
    }
    out
}

/// The 2-D map of a grid log's lattice `map`: two layers when the log
/// holds the grid both ways (`above`: the arrivals from above, `map` those
/// from below; see `GridMap::read`), else one.
fn grid_table(
    map: &GridMap,
    above: Option<&GridMap>,
) -> Result<(GridTable, crate::comp::GridBuildReport), crate::comp::CompError> {
    let offsets = |m: &GridMap| -> Vec<Option<[f64; 2]>> {
        m.cells.iter().map(|c| c.map(|c| c.e_um)).collect()
    };
    let above = above.map(offsets);
    GridTable::from_lattices(&map.xs_um, &map.ys_um, &offsets(map), above.as_deref())
}

/// Records `frame` in a log's metadata, as [`frame_from_metadata`] reads
/// it (full precision: a table built from the log must land in the same
/// frame).
pub fn frame_to_metadata(md: &mut Metadata, frame: &VisionFrame) {
    md.insert("vision_frame_rotation_rad", frame.rotation_rad.to_string());
    md.insert("vision_frame_mirrored", frame.mirrored.to_string());
    md.insert(
        "vision_frame_translation_x_um",
        frame.translation_um[0].to_string(),
    );
    md.insert(
        "vision_frame_translation_y_um",
        frame.translation_um[1].to_string(),
    );
}

/// The vision frame recorded in a log's metadata by the characterization
/// tie, if any.
pub fn frame_from_metadata(md: &Metadata) -> Result<Option<VisionFrame>, String> {
    let Some(rot) = md.get("vision_frame_rotation_rad") else {
        return Ok(None);
    };
    let num = |k: &str| -> Result<f64, String> {
        md.get(k)
            .ok_or_else(|| format!("metadata {k} missing"))?
            .parse::<f64>()
            .map_err(|_| format!("metadata {k} is not a number"))
    };
    let rotation_rad: f64 = rot
        .parse()
        .map_err(|_| "metadata vision_frame_rotation_rad is not a number".to_owned())?;
    let f = VisionFrame {
        rotation_rad,
        mirrored: md.get("vision_frame_mirrored") == Some("true"),
        translation_um: [
            num("vision_frame_translation_x_um")?,
            num("vision_frame_translation_y_um")?,
        ],
    };
    f.validate().map_err(|e| e.to_string())?;
    Ok(Some(f))
}

/// Seconds since the Unix epoch as RFC 3339 UTC text (civil-from-days, so no
/// date crate is needed for one timestamp).
pub fn rfc3339_utc(unix_s: u64) -> String {
    crate::clock::UtcTime::from_unix(unix_s).rfc3339()
}

fn bad(what: String) -> ProtoError {
    ProtoError::new(ErrorCode::BadValue, what)
}

/// Builds the requested tables from `params.log` (blocking: reads the log,
/// fits, writes files). Returns the reply fields and the written names.
pub fn build_blocking(
    data_dir: &Path,
    params: &TablesBuildParams,
) -> Result<(Value, Vec<String>), ProtoError> {
    let path = data_dir.join(&params.log);
    let bytes = crate::nofollow::read(&path).map_err(|e| {
        ProtoError::new(
            ErrorCode::LogError,
            format!("cannot read log {}: {e}", params.log),
        )
    })?;
    let parsed = log::parse_bytes(&bytes).map_err(|e| {
        ProtoError::new(
            ErrorCode::LogError,
            format!("log {}: {}", params.log, e.without_content()),
        )
    })?;
    let frame = frame_from_metadata(&parsed.metadata)
        .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("log {}: {e}", params.log)))?;
    // Reference re-measurements (`drift_every_s`): subtract the drift they
    // measure from every point before fitting; logs without them unchanged.
    let (undrifted, drift) = correct_log_drift(&parsed.records, LOG_DRIFT_METHOD)
        .map_err(|e| bad(format!("drift correction of {}: {e}", params.log)))?;
    let records = merged_scan_records(&undrifted);
    let stem = params.name.clone().unwrap_or_else(|| {
        params
            .log
            .strip_suffix(".csv")
            .unwrap_or(&params.log)
            .to_owned()
    });
    let unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let mut source = SourceInfo {
        log_path: Some(params.log.clone()),
        log_fnv1a64: Some(fnv1a64_hex(&bytes)),
        records: parsed.records.len() as u64,
        metadata: parsed
            .metadata
            .iter()
            .map(|(k, v)| (format!("log.{k}"), v.to_owned()))
            .collect(),
    };
    // The state of the rig the tables refer to: what live drift correction
    // measures against (`daemon::drift`).
    if let Some(d) = &drift {
        source.metadata.extend(d.baseline.to_metadata());
    }
    let mut written = Vec::new();
    let mut out = json!({"log": params.log, "frame": frame, "drift": drift});
    // The platform's yaw from the scans' θ, carried by the paper and the
    // model files (a log without θ: none, and no `yaw` in the reply).
    // A log whose θ cannot make tables (a scan without θ in one
    // direction) still builds its position tables; the reply says why
    // there is no yaw.
    let yaw = if kinds_want_scans(params) {
        match YawTables::from_records(&records, &TableBuildOptions::default()) {
            Ok(y) => y,
            Err(e) => {
                out["yaw"] = json!({"error": format!("no yaw tables: {e}")});
                None
            }
        }
    } else {
        None
    };
    if let Some((_, report)) = &yaw {
        out["yaw"] = json!({"report": report});
    }
    // The lattice, when a map may be asked for (named, or the default).
    let grid = (params.kinds.is_empty() || params.kinds.iter().any(|k| k == "grid"))
        .then(|| GridMap::read(&undrifted, [true, true]))
        .flatten();
    let kinds = if params.kinds.is_empty() {
        default_kinds(grid.is_some(), &records)
    } else {
        params.kinds.clone()
    };
    for kind in &kinds {
        let name = format!("{stem}-{kind}.toml");
        let mut file = if kind == "grid" {
            let (map, above) = grid.as_ref().ok_or_else(|| {
                bad(format!(
                    "{} is not a grid log (its targets do not fill a lattice of at least 3 × 3 \
                     positions with both axes measured): build paper or model tables from it",
                    params.log
                ))
            })?;
            let (mut table, report) = grid_table(map, above.as_ref())
                .map_err(|e| bad(format!("grid map from {}: {e}", params.log)))?;
            // microposd's one-way grid plan reaches every node from below.
            if parsed.metadata.get("plan") == Some("grid") && table.arrival == GridArrival::Unknown
            {
                table.arrival = GridArrival::FromBelow;
            }
            out["grid"] = json!({"name": name, "report": report});
            let mut f = CompFile::grid(table, rfc3339_utc(unix_s), source.clone());
            f.description = "2-D error map of a grid log, bilinear between its nodes".into();
            f
        } else if kind == "paper" {
            let (table, report) = CompTable::from_records(&records, &TableBuildOptions::default())
                .map_err(|e| bad(format!("paper tables from {}: {e}", params.log)))?;
            out["paper"] = json!({"name": name, "report": report});
            let mut f = CompFile::lookup(table, rfc3339_utc(unix_s), source.clone());
            f.description = "the paper's lookup tables (eqs. 4, 5) built by microposd".into();
            f
        } else {
            let base = StageModel::paper_default().map_err(|e| bad(e.to_string()))?;
            let (structure, extended_by) = extend_by_diagnosis(&parsed, &undrifted, base);
            // Moves of varied length make the move-length lost motion
            // identifiable: keep it if the diagnosis found it.
            let moves = records.iter().any(|r| r.segment == SEGMENT_MOVES);
            let template =
                compensation_template_for(&structure, moves).map_err(|e| bad(e.to_string()))?;
            let (comp, report) =
                ModelCompensator::fit_records(template, &records, &ModelBuildOptions::default())
                    .map_err(|e| bad(format!("model fit to {}: {e}", params.log)))?;
            let rms = report.residual_rms_um;
            source
                .metadata
                .insert("fit.rms_residual_um".into(), format!("{rms:?}"));
            source
                .metadata
                .insert("fit.extended_by".into(), extended_by.join(", "));
            // Why the fit could not identify what it could not, per
            // cause, with the step that would (issue 33: a bare list of 33
            // names). The fit's samples again: the same records, the same
            // options, so the same positions.
            let samples =
                crate::comp::model_comp::scan_samples(&records, &ModelBuildOptions::default())
                    .unwrap_or_default();
            let groups = crate::model::sampling::unidentifiable_groups(
                comp.model(),
                &report.unidentifiable,
                &samples,
            );
            out["model"] = json!({"name": name, "rms_residual_um": rms,
                                  "unidentifiable": report.unidentifiable,
                                  "unidentifiable_groups": groups,
                                  "extended_by": extended_by});
            let mut f = CompFile::model(comp.model(), rfc3339_utc(unix_s), source.clone())
                .map_err(|e| bad(e.to_string()))?;
            f.description = "stage model fitted to the scans by microposd".into();
            f
        };
        file.frame = frame;
        if kind != "grid" {
            file.yaw = yaw.as_ref().map(|(t, _)| t.clone());
        }
        // A map's area is its nodes' span (set by `CompFile::grid`); the
        // tables' and the model's is the scans'.
        if file.area.is_none() {
            file.area = crate::comp::Area::of_scans(&records);
        }
        let p = data_dir.join(&name);
        file.write_path(&p)
            .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("writing {name}: {e}")))?;
        written.push(name);
    }
    out["written"] = json!(written);
    Ok((out, written))
}

/// Whether the request may build scan tables (paper or model): only then
/// are yaw tables built (a grid log's map carries none).
fn kinds_want_scans(params: &TablesBuildParams) -> bool {
    params.kinds.is_empty() || params.kinds.iter().any(|k| k != "grid")
}

/// What `tables build` makes when the request names no kind: a 2-D map
/// of a grid log without scan segments, else the paper's tables and the
/// model table.
fn default_kinds(is_grid: bool, records: &[Record]) -> Vec<String> {
    let scans = records
        .iter()
        .any(|r| r.segment == SEGMENT_SCAN_X || r.segment == SEGMENT_SCAN_Y);
    if is_grid && !scans {
        vec!["grid".to_owned()]
    } else {
        vec!["paper".to_owned(), "model".to_owned()]
    }
}

/// The model structure a model table is fitted with: the paper default,
/// extended with the terms `diagnose` finds in this very log (held-out
/// judged, so noise does not add terms). Why: the default structure misses
/// what a real (or simulated) stage adds beyond it — measured on the served
/// rig's 50 µm scan: broad x(x) and y(y) curvature and extra scale left
/// 0.25 / 0.14 µm rms in the fit and 1.9 µm AP; the found terms take the
/// held-out rms to 0.05 / 0.03 µm. Terms of time or temperature are dropped
/// later by the compensation template (they cannot predict a later move).
/// Returns the structure and the names of the added terms; when the log
/// cannot be diagnosed (e.g. a single cycle: nothing to hold out) the
/// default structure, unchanged, with a warning.
fn extend_by_diagnosis(
    parsed: &log::MeasurementLog,
    records: &[Record],
    base: StageModel,
) -> (StageModel, Vec<String>) {
    let mut diag_log = parsed.clone();
    diag_log.records = records.to_vec();
    match diagnose(&diag_log, &base, &DiagnoseOptions::default()) {
        Ok(d) => {
            let names = d.findings.iter().map(|f| f.term.clone()).collect();
            (d.extended_model, names)
        }
        Err(e) => {
            tracing::warn!("tables build: no diagnosis of the log ({e}); default model structure");
            (base, Vec::new())
        }
    }
}

/// `tables build`: builds on a blocking thread, loads what it wrote,
/// optionally activates the first.
pub async fn build(rig: &Rig, params: TablesBuildParams) -> Result<Value, ProtoError> {
    let dir = rig.cfg.daemon.data_dir.clone();
    let p = params.clone();
    let (mut out, written) = tokio::task::spawn_blocking(move || build_blocking(&dir, &p))
        .await
        .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))??;
    for name in &written {
        rig.comp.load(&rig.cfg.daemon.data_dir, name).await?;
    }
    if params.activate {
        if let Some(first) = written.first() {
            out["active"] = Value::from(rig.comp.activate(Some(first))?.active);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(seg: &str, x: f64, y: f64) -> Record {
        Record {
            t_s: 0.0,
            segment: seg.into(),
            cycle: 1,
            x_target_um: x,
            y_target_um: y,
            x_cmd_um: x,
            y_cmd_um: y,
            x_meas_um: x,
            y_meas_um: y,
            temp_c: None,
            theta_urad: None,
            extra: vec![],
        }
    }

    /// A log of `records` with `md`, as written to the data directory.
    fn log_bytes(md: &Metadata, records: &[Record]) -> Vec<u8> {
        let mut w = log::LogWriter::create(
            Vec::new(),
            md,
            log::Columns::default(),
            log::SyncPolicy::FlushOnly,
        )
        .unwrap();
        for r in records {
            w.append(r).unwrap();
        }
        w.into_inner()
    }

    /// `tables build` of `log` in `dir` with the default kinds.
    fn build_default(dir: &Path, log: &str) -> (Value, Vec<String>) {
        let params = TablesBuildParams {
            log: log.into(),
            name: None,
            kinds: Vec::new(),
            activate: false,
        };
        build_blocking(dir, &params).unwrap()
    }

    /// A grid log (targets on a lattice, no scan segments) gets a 2-D map
    /// by default, whose prediction at a node is the error measured there;
    /// asking a scan log for a map is refused with the reason.
    #[test]
    fn a_grid_log_builds_a_map() {
        let mut md = Metadata::default();
        md.insert("source", "test lattice");
        let mut records = Vec::new();
        let e = |x: f64, y: f64| [1e-4 * x + 2e-8 * x * y, -3e-4 * y + 1e-8 * x * y];
        for iy in 0..6 {
            for ix in 0..7 {
                let (x, y) = (
                    2000.0 + 500.0 * f64::from(ix),
                    1000.0 + 800.0 * f64::from(iy),
                );
                let mut r = rec("grid", x, y);
                r.t_s = f64::from(iy * 7 + ix);
                let o = e(x, y);
                r.x_meas_um = x + o[0];
                r.y_meas_um = y + o[1];
                records.push(r);
            }
        }
        let bytes = |records: &[Record]| log_bytes(&md, records);
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("g.csv"), bytes(&records)).unwrap();
        let (out, written) = build_default(dir.path(), "g.csv");
        assert_eq!(written, ["g-grid.toml"], "{out}");
        assert_eq!(out["grid"]["report"]["measured"], 42, "{out}");
        let file = CompFile::read_path(dir.path().join("g-grid.toml")).unwrap();
        let comp = file.compensator().unwrap();
        assert_eq!(comp.kind(), "grid");
        let (x, y) = (3500.0, 2600.0);
        let p = comp
            .predicted_offset_um(&crate::model::MotionState::at_rest(x, y))
            .unwrap();
        let want = e(x, y);
        assert!(
            (p[0] - want[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9,
            "{p:?}"
        );
        assert_eq!(
            file.area.map(|a| (a.x_um, a.y_um)),
            Some(([2000.0, 5000.0], [1000.0, 5000.0]))
        );

        // A scan (two lines) is no grid.
        let scans: Vec<Record> = (0..10)
            .map(|i| rec(SEGMENT_SCAN_X, 1000.0 * f64::from(i), 7500.0))
            .collect();
        std::fs::write(dir.path().join("s.csv"), bytes(&scans)).unwrap();
        let params = TablesBuildParams {
            log: "s.csv".into(),
            name: None,
            kinds: vec!["grid".into()],
            activate: false,
        };
        let e = build_blocking(dir.path(), &params).unwrap_err();
        assert!(e.to_string().contains("not a grid log"), "{e}");
    }

    /// A grid log measured both ways (segments `grid_fwd`, `grid_bwd`)
    /// gives a two-layer map: a move arriving from above on x and from
    /// below on y gets the x play and no y play; the reply names the
    /// reversal.
    #[test]
    fn a_grid_measured_both_ways_builds_a_map_per_direction() {
        use crate::charact::scan::{SEGMENT_GRID_BWD, SEGMENT_GRID_FWD};
        use crate::model::{AxisMotion, Direction, MotionState};
        let mut md = Metadata::default();
        md.insert("plan", "grid");
        md.insert("grid_approach", "both");
        let e = |x: f64, y: f64| [1e-4 * x + 2e-8 * x * y, -3e-4 * y];
        let play = [1.7, -0.6];
        let mut records = Vec::new();
        for (seg, sign) in [(SEGMENT_GRID_FWD, 0.0), (SEGMENT_GRID_BWD, 1.0)] {
            for iy in 0..5 {
                for ix in 0..4 {
                    let (x, y) = (500.0 * f64::from(ix), 700.0 * f64::from(iy));
                    let mut r = rec(seg, x, y);
                    let o = e(x, y);
                    r.x_meas_um = x + o[0] + sign * play[0];
                    r.y_meas_um = y + o[1] + sign * play[1];
                    records.push(r);
                }
            }
        }
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("b.csv"), log_bytes(&md, &records)).unwrap();
        let (out, written) = build_default(dir.path(), "b.csv");
        assert_eq!(written, ["b-grid.toml"], "{out}");
        let rev = &out["grid"]["report"]["reversal_rms_um"];
        assert!((rev[0].as_f64().unwrap() - 1.7).abs() < 1e-9, "{out}");
        assert_eq!(out["grid"]["report"]["measured_from_above"], 20, "{out}");
        let file = CompFile::read_path(dir.path().join("b-grid.toml")).unwrap();
        let comp = file.compensator().unwrap();
        let (x, y) = (750.0, 1000.0);
        let mut state = MotionState::at_rest(x, y);
        state.axes[0] = AxisMotion {
            dir: Direction::Backward,
            ..state.axes[0]
        };
        state.axes[1] = AxisMotion {
            dir: Direction::Forward,
            ..state.axes[1]
        };
        let p = comp.predicted_offset_um(&state).unwrap();
        let want = e(x, y);
        assert!(
            (p[0] - want[0] - play[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9,
            "{p:?}"
        );
    }

    /// A stage with an effect the default model lacks (a periodic error
    /// at a period other than the screw's): the model table takes the term
    /// `diagnose` finds and fits the scans to the noise, where the default
    /// structure cannot.
    #[test]
    fn model_table_takes_the_structure_the_log_shows() {
        use crate::analysis::generate::{draw_effect, simulate_log, truth_model, SimPlan};
        use crate::analysis::FindingKind;
        let plan = SimPlan::default();
        let e = draw_effect(42, Some(FindingKind::PositionPeriodic), &plan).unwrap();
        let truth =
            truth_model(&StageModel::paper_default().unwrap(), Some(&e), &plan, 42).unwrap();
        let bytes = simulate_log(&truth, &plan, 42).unwrap().to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("c.csv"), &bytes).unwrap();
        let params = TablesBuildParams {
            log: "c.csv".into(),
            name: None,
            kinds: vec!["model".into()],
            activate: false,
        };
        let (out, written) = build_blocking(dir.path(), &params).unwrap();
        assert_eq!(written, vec!["c-model.toml".to_owned()]);
        let ext = out["model"]["extended_by"].as_array().unwrap();
        assert_eq!(ext.len(), 1, "{out}");
        // Every unidentifiable parameter is in exactly one group, which
        // says why and what would identify it.
        let strs = |v: &Value| -> Vec<String> {
            v.as_array()
                .unwrap()
                .iter()
                .map(|s| s.as_str().unwrap().to_owned())
                .collect()
        };
        let mut names = strs(&out["model"]["unidentifiable"]);
        let groups = out["model"]["unidentifiable_groups"].as_array().unwrap();
        let mut grouped: Vec<String> = groups.iter().flat_map(|g| strs(&g["params"])).collect();
        assert!(groups
            .iter()
            .all(|g| g["advice"].as_str().is_some_and(|a| !a.is_empty())));
        names.sort();
        grouped.sort();
        assert_eq!(names, grouped, "{out}");
        let extended_rms = out["model"]["rms_residual_um"][e.component as usize]
            .as_f64()
            .unwrap();
        // The default structure alone, fitted to the same scans.
        let parsed = log::parse_bytes(&bytes).unwrap();
        let template =
            crate::comp::compensation_template(&StageModel::paper_default().unwrap()).unwrap();
        let (_, report) = ModelCompensator::fit_records(
            template,
            &merged_scan_records(&parsed.records),
            &ModelBuildOptions::default(),
        )
        .unwrap();
        let default_rms = report.residual_rms_um[e.component as usize];
        // Both leave the log's thermal drift (no time terms in a table); the
        // extended structure must explain at least half of the effect's
        // variance (a sine of amplitude A has variance A²/2).
        let a = e.params["amplitude_um"];
        let explained = default_rms.powi(2) - extended_rms.powi(2);
        assert!(
            explained > 0.5 * a * a / 2.0,
            "extended {extended_rms} µm vs default {default_rms} µm, effect amplitude {a} µm"
        );
    }

    #[test]
    fn passes_merge_and_turn_repeats_drop() {
        let r = vec![
            rec("scan_x_fwd", 0.0, 5.0),
            rec("scan_x_fwd", 10.0, 5.0),
            rec("scan_x_bwd", 10.0, 5.0),
            rec("scan_x_bwd", 0.0, 5.0),
            rec("scan_y_fwd", 5.0, 0.0),
            rec("square", 1.0, 1.0),
        ];
        let m = merged_scan_records(&r);
        let segs: Vec<&str> = m.iter().map(|r| r.segment.as_str()).collect();
        assert_eq!(segs, ["scan_x", "scan_x", "scan_x", "scan_y", "square"]);
        assert_eq!(m[2].x_cmd_um, 0.0);
    }

    #[test]
    fn rfc3339_of_known_instants() {
        assert_eq!(rfc3339_utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(rfc3339_utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(rfc3339_utc(1_795_000_000), "2026-11-18T11:06:40Z");
    }

    #[test]
    fn frame_metadata_round_trip_and_errors() {
        let mut md = Metadata::new();
        assert_eq!(frame_from_metadata(&md), Ok(None));
        md.insert("vision_frame_rotation_rad", "3.1");
        assert!(frame_from_metadata(&md).is_err());
        md.insert("vision_frame_translation_x_um", "1");
        md.insert("vision_frame_translation_y_um", "-2");
        md.insert("vision_frame_mirrored", "false");
        let f = frame_from_metadata(&md).unwrap().unwrap();
        assert_eq!(f.translation_um, [1.0, -2.0]);
        md.insert("vision_frame_rotation_rad", "9");
        assert!(frame_from_metadata(&md).is_err());
        // What a job writes reads back bit for bit.
        let frame = VisionFrame {
            rotation_rad: -3.136_356_6,
            mirrored: true,
            translation_um: [0.1 + 0.2, -1e-17],
        };
        let mut md = Metadata::new();
        frame_to_metadata(&mut md, &frame);
        assert_eq!(frame_from_metadata(&md), Ok(Some(frame)));
    }
}
