//! `figures`: the paper's figures of the newest characterization or
//! validation log (or of a named one) as data, for the web page and for
//! scripts.
//!
//! Why a socket command: the socket protocol is the one source of truth,
//! so the page can show only what a socket client can read; this is the
//! read-only way to a log's analysis (role `read`, changes nothing).
//! Why data and not images: the figures are `plot`'s own [`Figure`]s, the
//! ones `micropos plot` writes as PNG/SVG, serialized (panels, traces,
//! points); the browser draws them, so a page and a file show one
//! computation and the daemon encodes no image per request.
//!
//! Which log: `log` names it; without it, the newest file (modification
//! time) in the data directory whose header says `job: characterize` (or
//! `validate`): the log a running job appends to is the newest of its
//! kind, so the page follows a running job. Logs written by other
//! programs carry no `job` key and are read only by name.
//!
//! Reading and analysing a log is file I/O and CPU (a paper-sized log has
//! ~16 000 records): it runs on the blocking pool, never on the runtime.

use crate::charact::log::{read_file, LogError, LogReader, MeasurementLog};
use crate::daemon::protocol::{ErrorCode, FiguresJob, FiguresParams, ProtoError};
use crate::model::Axis;
use crate::plot::charact::{
    backlash_um, cycles, fig4_errors, fig5_coupling, fig6_repeatability, mean_errors,
    repeatability, scans, Scan,
};
use crate::plot::figure::Figure;
use crate::plot::validation::{gather, has_validation, validation_figure};
use serde_json::{json, Value};
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// `figures` on the blocking pool.
pub async fn figures(data_dir: &Path, p: FiguresParams) -> Result<Value, ProtoError> {
    let dir = data_dir.to_path_buf();
    tokio::task::spawn_blocking(move || figures_in(&dir, &p))
        .await
        .map_err(|e| ProtoError::new(ErrorCode::Internal, format!("figures: {e}")))?
}

/// The reply of `figures` for the logs in `dir` (blocking).
pub fn figures_in(dir: &Path, p: &FiguresParams) -> Result<Value, ProtoError> {
    let name = match &p.log {
        Some(n) => n.clone(),
        None => newest_log(dir, p.job)?.ok_or_else(|| {
            let what = match p.job {
                FiguresJob::Characterize => "characterization",
                FiguresJob::Validate => "validation",
            };
            ProtoError::new(
                ErrorCode::LogError,
                format!(
                    "no {what} yet: no log in the data directory has `job: {}` (run {} start)",
                    p.job.as_str(),
                    p.job.as_str()
                ),
            )
        })?,
    };
    let log = read_file(dir.join(&name)).map_err(|e| match e {
        LogError::Io(io) if io.kind() == std::io::ErrorKind::NotFound => ProtoError::new(
            ErrorCode::LogError,
            format!("log {name} not found in the data directory"),
        ),
        e => ProtoError::new(
            ErrorCode::LogError,
            format!("cannot read {name}: {}", e.without_content()),
        ),
    })?;
    let mut reply = match p.job {
        FiguresJob::Characterize => characterization(&name, &log)?,
        FiguresJob::Validate => validation(&name, &log)?,
    };
    if let Some(t) = &log.torn_tail {
        if let Some(notes) = reply["notes"].as_array_mut() {
            notes.push(json!(format!(
                "{name}: unterminated last line {} left out (a job may be writing it)",
                t.line
            )));
        }
    }
    Ok(reply)
}

/// The newest log in `dir` whose metadata says `job: <job>`; `None` if
/// there is none. Files whose header does not parse (tables, the audit
/// trail) are skipped; hidden files too.
pub fn newest_log(dir: &Path, job: FiguresJob) -> Result<Option<String>, ProtoError> {
    let entries = std::fs::read_dir(dir).map_err(|e| {
        ProtoError::new(
            ErrorCode::LogError,
            format!("cannot list the data directory {}: {e}", dir.display()),
        )
    })?;
    let mut files: Vec<(SystemTime, String)> = entries
        .filter_map(Result::ok)
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let md = e.metadata().ok()?;
            (md.is_file() && !name.starts_with('.')).then_some((md.modified().ok()?, name))
        })
        .collect();
    // Newest first; equal times by name, so the answer does not depend on
    // the directory's order.
    files.sort_by(|a, b| b.cmp(a));
    for (_, name) in files {
        let path: PathBuf = dir.join(&name);
        let Ok(f) = crate::nofollow::open(&path) else {
            continue;
        };
        let Ok(r) = LogReader::new(BufReader::new(f)) else {
            continue;
        };
        if r.metadata().get("job") == Some(job.as_str()) {
            return Ok(Some(name));
        }
    }
    Ok(None)
}

fn axis_name(a: Axis) -> &'static str {
    match a {
        Axis::X => "x",
        Axis::Y => "y",
    }
}

fn to_json(figs: &[Figure]) -> Result<Value, ProtoError> {
    serde_json::to_value(figs).map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))
}

fn max_abs(v: impl Iterator<Item = f64>) -> Option<f64> {
    v.filter(|x| x.is_finite()).map(f64::abs).reduce(f64::max)
}

/// The summary of one scan: the numbers a person reads off Figs. 4–6.
fn scan_summary(s: &Scan) -> Value {
    let [fwd, bwd] = mean_errors(s);
    let [rf, rb] = repeatability(s);
    let pairs = |v: &[(f64, f64)]| v.iter().map(|&(t, e)| json!([t, e])).collect::<Vec<_>>();
    json!({
        "axis": axis_name(s.axis),
        "points": s.points.len(),
        "undetermined": s.undetermined,
        "cycles": cycles(s),
        "max_abs_error_um": max_abs(s.points.iter().map(|p| p.along_um)),
        "max_abs_coupling_um": max_abs(s.points.iter().map(|p| p.across_um)),
        "backlash_um": backlash_um(s),
        "rp_max_um": rf.iter().chain(&rb).map(|p| p.1).reduce(f64::max),
        "mean_error_um": {"forward": pairs(&fwd), "backward": pairs(&bwd)},
    })
}

/// Figs. 4–6 of a characterization log with a summary per scanned axis.
pub fn characterization(name: &str, log: &MeasurementLog) -> Result<Value, ProtoError> {
    let scans: Vec<Scan> = scans(log)
        .into_iter()
        .flatten()
        .filter(|s| !s.points.is_empty())
        .collect();
    if scans.is_empty() {
        return Err(ProtoError::new(
            ErrorCode::LogError,
            format!(
                "{name} holds no scan_x/scan_y point with a known direction yet ({} record(s))",
                log.records.len()
            ),
        ));
    }
    let mut notes = Vec::new();
    for s in &scans {
        if s.undetermined > 0 {
            notes.push(format!(
                "scan_{}: {} point(s) without a direction left out",
                axis_name(s.axis),
                s.undetermined
            ));
        }
    }
    let mut figs = vec![fig4_errors(name, &scans), fig5_coupling(name, &scans)];
    match fig6_repeatability(name, &scans) {
        Some(f) => figs.push(f),
        None => notes.push(
            "no target visited twice in one direction: no repeatability figure (needs ≥ 2 cycles)"
                .to_owned(),
        ),
    }
    Ok(json!({
        "job": FiguresJob::Characterize.as_str(),
        "log": name,
        "records": log.records.len(),
        "axes": scans.iter().map(scan_summary).collect::<Vec<_>>(),
        "figures": to_json(&figs)?,
        "notes": notes,
    }))
}

/// Figs. 10–11 of a validation log with ISO 9283 AP/RP per test and mode.
pub fn validation(name: &str, log: &MeasurementLog) -> Result<Value, ProtoError> {
    if !has_validation(log) {
        return Err(ProtoError::new(
            ErrorCode::LogError,
            format!(
                "{name} holds no square/random record yet ({} record(s))",
                log.records.len()
            ),
        ));
    }
    let stem = Path::new(name)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or(name);
    let (sets, notes) = gather(&[(name, stem, log)]);
    let mut results = Vec::new();
    for v in &sets {
        for m in &v.modes {
            let Some(s) = m.summary(&v.poses) else {
                continue;
            };
            results.push(json!({
                "test": v.segment,
                "mode": m.name,
                "poses": s.poses,
                "ap_max_um": s.ap_max_um,
                "ap_mean_um": s.ap_mean_um,
                "rp_max_um": s.rp_max_um,
                "rp_mean_um": s.rp_mean_um,
            }));
        }
    }
    let figs: Vec<Figure> = sets.iter().map(validation_figure).collect();
    Ok(json!({
        "job": FiguresJob::Validate.as_str(),
        "log": name,
        "records": log.records.len(),
        "results": results,
        "figures": to_json(&figs)?,
        "notes": notes,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::charact::log::parse_bytes;
    use rand::{Rng, SeedableRng};
    use std::fmt::Write as _;
    use std::fs::File;
    use std::time::Duration;

    const HEADER: &str =
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um";

    /// A stage of known errors: along each axis a cyclic error of
    /// amplitude `cyclic_um` and a backlash `backlash_um` (forward stops
    /// `backlash_um / 2` short, backward as much beyond), a coupling
    /// offset; camera noise of ±`noise_um`.
    struct Truth {
        backlash_um: [f64; 2],
        cyclic_um: f64,
        coupling_um: f64,
        noise_um: f64,
        cycles: u32,
        step_um: f64,
    }

    fn random_truth(rng: &mut rand::rngs::StdRng) -> Truth {
        let sign = |r: &mut rand::rngs::StdRng| if r.gen_bool(0.5) { 1.0 } else { -1.0 };
        Truth {
            backlash_um: [
                sign(rng) * rng.gen_range(0.2..5.0),
                sign(rng) * rng.gen_range(0.2..5.0),
            ],
            cyclic_um: sign(rng) * rng.gen_range(0.0..3.0),
            coupling_um: sign(rng) * rng.gen_range(0.0..2.0),
            noise_um: rng.gen_range(0.0..0.01),
            cycles: rng.gen_range(2..4),
            step_um: rng.gen_range(50.0..200.0),
        }
    }

    /// The log text the daemon's characterization writes for `t`
    /// (passes `scan_x_fwd` / `scan_x_bwd`, then Y).
    fn charact_log(t: &Truth, rng: &mut rand::rngs::StdRng) -> String {
        let mut s = format!("# job: characterize\n{HEADER}\n");
        let mut time = 0.0;
        for (axis, seg) in [(0, "scan_x"), (1, "scan_y")] {
            for cycle in 1..=t.cycles {
                let fwd: Vec<f64> = (0..=8).map(|k| 100.0 + t.step_um * k as f64).collect();
                let bwd: Vec<f64> = fwd.iter().rev().copied().collect();
                for (dir, pass, suffix) in [(0.5, fwd, "fwd"), (-0.5, bwd, "bwd")] {
                    for p in pass {
                        let mut noise = || rng.gen_range(-t.noise_um..=t.noise_um);
                        let along =
                            t.cyclic_um * (p / 300.0).sin() + dir * t.backlash_um[axis] + noise();
                        let across = t.coupling_um + noise();
                        let (xt, yt, ex, ey) = if axis == 0 {
                            (p, 50.0, along, across)
                        } else {
                            (50.0, p, across, along)
                        };
                        writeln!(
                            s,
                            "{time:.3},{seg}_{suffix},{cycle},{xt},{yt},{xt},{yt},{:.6},{:.6}",
                            xt - ex,
                            yt - ey
                        )
                        .unwrap();
                        time += 1.0;
                    }
                }
            }
        }
        s
    }

    fn params(job: FiguresJob, log: Option<&str>) -> FiguresParams {
        FiguresParams {
            job,
            log: log.map(str::to_owned),
        }
    }

    fn set_mtime(path: &Path, secs: u64) {
        let f = File::options().write(true).open(path).unwrap();
        f.set_modified(SystemTime::UNIX_EPOCH + Duration::from_secs(secs))
            .unwrap();
    }

    #[test]
    fn characterization_figures_carry_the_logs_own_analysis() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(0x5eed_0f16);
        for _ in 0..8 {
            let t = random_truth(&mut rng);
            let text = charact_log(&t, &mut rng);
            let log = parse_bytes(text.as_bytes()).unwrap();
            let r = characterization("c.csv", &log).unwrap();
            assert_eq!(r["log"], "c.csv");
            assert_eq!(r["records"], log.records.len());
            let axes = r["axes"].as_array().unwrap();
            assert_eq!(axes.len(), 2);
            for (k, a) in axes.iter().enumerate() {
                assert_eq!(a["axis"], ["x", "y"][k]);
                assert_eq!(a["cycles"], t.cycles);
                let b = a["backlash_um"].as_f64().unwrap();
                assert!(
                    (b - t.backlash_um[k]).abs() < 2.0 * t.noise_um + 1e-5,
                    "axis {k}: backlash {b} vs {}",
                    t.backlash_um[k]
                );
                let c = a["max_abs_coupling_um"].as_f64().unwrap();
                assert!((c - t.coupling_um.abs()).abs() <= t.noise_um + 1e-5);
                // Forward means: cyclic error + half the backlash.
                for pt in a["mean_error_um"]["forward"].as_array().unwrap() {
                    let (p, e) = (pt[0].as_f64().unwrap(), pt[1].as_f64().unwrap());
                    let want = t.cyclic_um * (p / 300.0).sin() + 0.5 * t.backlash_um[k];
                    assert!((e - want).abs() <= t.noise_um + 1e-5, "{p}: {e} vs {want}");
                }
                assert!(a["rp_max_um"].as_f64().unwrap() >= 0.0);
            }
            // The figures are plot's, on the same scans: Fig. 4's traces
            // hold every point's error along the moving axis.
            let figs = r["figures"].as_array().unwrap();
            assert_eq!(figs.len(), 3, "Figs. 4, 5, 6");
            let [sx, _] = scans(&log);
            let sx = sx.unwrap();
            let panel = &figs[0]["rows"][0][0];
            assert_eq!(panel["kind"], "xy");
            let traces = panel["traces"].as_array().unwrap();
            assert_eq!(traces.len(), 2 * t.cycles as usize, "one trace per pass");
            let mut drawn: Vec<(f64, f64)> = traces
                .iter()
                .flat_map(|tr| tr["points"].as_array().unwrap().iter())
                .map(|p| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
                .collect();
            let mut want: Vec<(f64, f64)> = sx
                .points
                .iter()
                .map(|p| (p.target_um, p.along_um))
                .collect();
            drawn.sort_by(|a, b| a.partial_cmp(b).unwrap());
            want.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(drawn, want);
            assert!(r["notes"].as_array().unwrap().is_empty(), "{}", r["notes"]);
        }
    }

    #[test]
    fn one_cycle_has_no_repeatability_figure_and_says_so() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut t = random_truth(&mut rng);
        t.cycles = 1;
        let log = parse_bytes(charact_log(&t, &mut rng).as_bytes()).unwrap();
        let r = characterization("one.csv", &log).unwrap();
        assert_eq!(r["figures"].as_array().unwrap().len(), 2);
        assert!(r["notes"][0].as_str().unwrap().contains("≥ 2 cycles"));
        assert!(r["axes"][0]["rp_max_um"].is_null());
    }

    #[test]
    fn validation_reports_ap_and_rp_per_mode() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(0xa9);
        let offsets: Vec<(&str, f64)> = ["raw", "table"]
            .into_iter()
            .map(|m| (m, rng.gen_range(-20.0..20.0)))
            .collect();
        let mut s = format!("# job: validate\n{HEADER},mode,pose\n");
        for (mode, off) in &offsets {
            for cycle in 1..=3 {
                for pose in 0..5 {
                    let (x, y) = (100.0 * pose as f64, 40.0);
                    writeln!(
                        s,
                        "0,square,{cycle},{x},{y},{x},{y},{},{y},{mode},{pose}",
                        x + off
                    )
                    .unwrap();
                }
            }
        }
        let log = parse_bytes(s.as_bytes()).unwrap();
        let r = validation("v.csv", &log).unwrap();
        let results = r["results"].as_array().unwrap();
        assert_eq!(results.len(), 2);
        for (res, (mode, off)) in results.iter().zip(&offsets) {
            assert_eq!(res["test"], "square");
            assert_eq!(res["mode"], *mode);
            assert_eq!(res["poses"], 5);
            let ap = res["ap_max_um"].as_f64().unwrap();
            assert!((ap - off.abs()).abs() < 1e-6, "{mode}: AP {ap} vs {off}");
            assert!(res["rp_max_um"].as_f64().unwrap() < 1e-6);
        }
        assert_eq!(r["figures"].as_array().unwrap().len(), 1, "Fig. 10 only");
        // A characterization log is not a validation and vice versa.
        let e = characterization("v.csv", &log).unwrap_err();
        assert_eq!(e.code, ErrorCode::LogError);
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let t = random_truth(&mut rng);
        let c = parse_bytes(charact_log(&t, &mut rng).as_bytes()).unwrap();
        assert_eq!(
            validation("c.csv", &c).unwrap_err().code,
            ErrorCode::LogError
        );
    }

    #[test]
    fn the_newest_log_of_each_job_is_found() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // Nothing yet: a clear error naming what to run.
        let e = figures_in(d, &params(FiguresJob::Characterize, None)).unwrap_err();
        assert_eq!(e.code, ErrorCode::LogError);
        assert!(e.message.starts_with("no characterization yet"), "{e}");
        let e = figures_in(d, &params(FiguresJob::Validate, None)).unwrap_err();
        assert!(e.message.starts_with("no validation yet"), "{e}");

        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let t = random_truth(&mut rng);
        std::fs::write(d.join("a.csv"), charact_log(&t, &mut rng)).unwrap();
        std::fs::write(d.join("b.csv"), charact_log(&t, &mut rng)).unwrap();
        std::fs::write(
            d.join("v.csv"),
            format!("# job: validate\n{HEADER}\n0,square,1,0,0,0,0,0.5,0\n"),
        )
        .unwrap();
        // Not logs, or not the daemon's: skipped, however new.
        std::fs::write(d.join("audit.jsonl"), "{\"cmd\":\"move\"}\n").unwrap();
        std::fs::write(d.join("t-paper.toml"), "interpolation = \"linear\"\n").unwrap();
        std::fs::write(d.join("import.csv"), format!("{HEADER}\n")).unwrap();
        std::fs::write(d.join(".hidden.csv"), charact_log(&t, &mut rng)).unwrap();
        for (name, secs) in [
            ("a.csv", 1000),
            ("b.csv", 2000),
            ("v.csv", 1500),
            ("audit.jsonl", 9000),
            ("t-paper.toml", 9000),
            ("import.csv", 9000),
            (".hidden.csv", 9000),
        ] {
            set_mtime(&d.join(name), secs);
        }
        assert_eq!(
            newest_log(d, FiguresJob::Characterize).unwrap().as_deref(),
            Some("b.csv")
        );
        assert_eq!(
            newest_log(d, FiguresJob::Validate).unwrap().as_deref(),
            Some("v.csv")
        );
        set_mtime(&d.join("a.csv"), 3000);
        let r = figures_in(d, &params(FiguresJob::Characterize, None)).unwrap();
        assert_eq!(r["log"], "a.csv");
        // By name, any log of the right content.
        let r = figures_in(d, &params(FiguresJob::Characterize, Some("b.csv"))).unwrap();
        assert_eq!(r["log"], "b.csv");
        let r = figures_in(d, &params(FiguresJob::Validate, None)).unwrap();
        assert_eq!(r["results"][0]["ap_max_um"], 0.5);
        // A missing data directory is an error too, not a panic.
        let e = newest_log(&d.join("nope"), FiguresJob::Validate).unwrap_err();
        assert_eq!(e.code, ErrorCode::LogError);
    }

    #[test]
    fn bad_logs_are_error_replies() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let e = figures_in(d, &params(FiguresJob::Characterize, Some("gone.csv"))).unwrap_err();
        assert_eq!(e.code, ErrorCode::LogError);
        assert!(e.message.contains("gone.csv not found"), "{e}");
        // A corrupted record, a header alone, a file that is not a log.
        let cases = [
            (
                "corrupt.csv",
                format!("# job: characterize\n{HEADER}\n0,scan_x_fwd,1,0,0,0,0,zero,0\n"),
                "cannot read corrupt.csv: line 3",
            ),
            (
                "empty.csv",
                format!("# job: characterize\n{HEADER}\n"),
                "no scan_x/scan_y point",
            ),
            ("binary.csv", "\u{0}\u{1}PNG\n".to_owned(), "cannot read"),
        ];
        for (name, text, why) in cases {
            std::fs::write(d.join(name), text).unwrap();
            let e = figures_in(d, &params(FiguresJob::Characterize, Some(name))).unwrap_err();
            assert_eq!(e.code, ErrorCode::LogError, "{name}");
            assert!(e.message.contains(why), "{name}: {e}");
        }
        // The newest characterization is the corrupted one: an error
        // reply that names it, not an older log's figures.
        set_mtime(&d.join("corrupt.csv"), 5000);
        set_mtime(&d.join("empty.csv"), 4000);
        let e = figures_in(d, &params(FiguresJob::Characterize, None)).unwrap_err();
        assert!(e.message.contains("corrupt.csv"), "{e}");
    }

    #[test]
    fn arbitrary_bytes_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut rng = rand::rngs::StdRng::seed_from_u64(0xbad);
        let t = random_truth(&mut rng);
        let good = charact_log(&t, &mut rng).into_bytes();
        for i in 0..200 {
            // A valid log cut and overwritten at random places, or noise.
            let mut bytes = if i % 4 == 0 {
                (0..rng.gen_range(0..400)).map(|_| rng.gen()).collect()
            } else {
                good[..rng.gen_range(0..good.len())].to_vec()
            };
            for _ in 0..rng.gen_range(0..4) {
                if !bytes.is_empty() {
                    let k = rng.gen_range(0..bytes.len());
                    bytes[k] = rng.gen();
                }
            }
            std::fs::write(d.join("x.csv"), &bytes).unwrap();
            for job in [FiguresJob::Characterize, FiguresJob::Validate] {
                if let Err(e) = figures_in(d, &params(job, Some("x.csv"))) {
                    assert_eq!(e.code, ErrorCode::LogError, "{e}");
                }
            }
        }
    }

    /// A link planted in the data directory (anonymous HTTP `figures`
    /// names it) is refused without quoting the target's first line.
    #[test]
    fn a_planted_link_is_refused_without_quoting_its_target() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let secret = d.join("outside");
        std::fs::write(&secret, "root:secret-hash:0:0\n").unwrap();
        std::os::unix::fs::symlink(&secret, d.join("x.csv")).unwrap();
        for job in [FiguresJob::Characterize, FiguresJob::Validate] {
            let e = figures_in(d, &params(job, Some("x.csv"))).unwrap_err();
            assert_eq!(e.code, ErrorCode::LogError, "{e}");
            assert!(!e.to_string().contains("secret-hash"), "{e}");
            assert!(e.to_string().contains("symbolic link"), "{e}");
        }
    }

    /// A real file in the data directory that is not a log (a misplaced
    /// secret) is refused with its line, never its text.
    #[test]
    fn a_file_that_is_not_a_log_is_refused_without_quoting_it() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("x.csv"), "root:secret-hash:0:0\n").unwrap();
        for job in [FiguresJob::Characterize, FiguresJob::Validate] {
            let e = figures_in(d, &params(job, Some("x.csv"))).unwrap_err();
            assert_eq!(e.code, ErrorCode::LogError, "{e}");
            assert!(!e.to_string().contains("secret-hash"), "{e}");
            assert!(e.to_string().contains("line 1"), "{e}");
        }
    }
}
