//! From measurement logs to every figure they support: what `micropos plot`
//! and the main job (`hil-sim run --plots DIR`) call.
//!
//! Each log is inspected for what it holds: `scan_x` / `scan_y` segments
//! give the characterization figures (Figs. 4, 5, 6 of the paper);
//! `square` / `random` segments give the validation figures (Figs. 10,
//! 11). A log with neither is refused: plotting it was asked for and
//! nothing would come out.
//!
//! One run per figure: every log gets figures of its own, so the AP and RP
//! a figure shows are those its run printed. Logs of several runs share a
//! figure only when a comparison is asked for (`compare`, `micropos plot
//! --compare`): then the validation figures hold one series per log and
//! mode, labelled `mode (log)`; records of one mode from different logs
//! are never pooled.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use super::charact::{charact_figures, scans};
use super::figure::{render_figure, Format, NamedFigure};
use super::validation::{has_validation, validation_figures};
use super::{ensure_dir, PlotError};
use crate::charact::log::{read_file, MeasurementLog};

/// A parsed log with the names it is shown and written under.
#[derive(Debug, Clone)]
pub struct NamedLog {
    /// How titles and notes name it (usually the file name).
    pub name: String,
    /// File-name-safe stem for the output files (and the mode name of a
    /// validation log without a `mode` column).
    pub stem: String,
    /// The parsed log.
    pub log: MeasurementLog,
}

/// What was written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Plotted {
    /// Files written, in order.
    pub files: Vec<PathBuf>,
    /// Things the user should know (points left out, figures skipped,
    /// assumptions such as a missing `mode` column).
    pub notes: Vec<String>,
    /// The figures the files show, as data.
    pub figures: Vec<NamedFigure>,
}

/// The figures a set of logs supports, before drawing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FigureSet {
    /// Figures with their file stems, in order.
    pub figures: Vec<NamedFigure>,
    /// Things the user should know (see [`Plotted::notes`]).
    pub notes: Vec<String>,
}

/// What a log holds, as far as plotting is concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Contents {
    /// Has `scan_x` and/or `scan_y` records.
    pub characterization: bool,
    /// Has `square` and/or `random` records.
    pub validation: bool,
}

/// Inspects a log.
pub fn contents(log: &MeasurementLog) -> Contents {
    Contents {
        characterization: scans(log).iter().flatten().any(|s| !s.points.is_empty()),
        validation: has_validation(log),
    }
}

fn safe_stem(path: &Path) -> String {
    let s: String = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
        .chars()
        .map(|c| {
            if c.is_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "log".into()
    } else {
        s
    }
}

/// Reads logs from files, naming each after its file. Errors name the file
/// and why it cannot be read.
pub fn read_logs<P: AsRef<Path>>(paths: &[P]) -> Result<Vec<NamedLog>, PlotError> {
    paths
        .iter()
        .map(|p| {
            let p = p.as_ref();
            let log = read_file(p).map_err(|reason| PlotError::Log {
                path: p.to_path_buf(),
                reason,
            })?;
            Ok(NamedLog {
                name: p.file_name().map_or_else(
                    || p.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                ),
                stem: safe_stem(p),
                log,
            })
        })
        .collect()
}

/// Every figure the logs support: per characterization log
/// `<stem>_fig4_errors`, `<stem>_fig5_coupling`, `<stem>_fig6_repeatability`;
/// per validation log `<stem>_fig10_square`, `<stem>_fig11_random`. With
/// `compare`, the validation records of all logs share
/// `validation_fig10_square` / `validation_fig11_random` instead (one
/// series per log and mode; the log's stem when only one log holds
/// validation records). Refused: no log, or a log with nothing to plot.
pub fn figure_set(logs: &[NamedLog], compare: bool) -> Result<FigureSet, PlotError> {
    if logs.is_empty() {
        return Err(PlotError::Nothing {
            what: "no log given".into(),
        });
    }
    let mut out = FigureSet::default();
    let mut used = HashSet::new();
    let mut stems = Vec::with_capacity(logs.len());
    for l in logs {
        let c = contents(&l.log);
        if !c.characterization && !c.validation {
            let mut segs: Vec<&str> = l.log.records.iter().map(|r| r.segment.as_str()).collect();
            segs.sort_unstable();
            segs.dedup();
            return Err(PlotError::Nothing {
                what: format!(
                    "{}: no scan_x, scan_y, square or random records to plot (segments found: {})",
                    l.name,
                    if segs.is_empty() {
                        "none".into()
                    } else {
                        segs.join(", ")
                    }
                ),
            });
        }
        // Two logs with the same file stem (from two directories) must not
        // overwrite each other's figures.
        let mut stem = l.stem.clone();
        let mut k = 2;
        while !used.insert(stem.clone()) {
            stem = format!("{}_{k}", l.stem);
            k += 1;
        }
        stems.push(stem);
    }
    for (l, stem) in logs.iter().zip(&stems) {
        let (figures, notes) = charact_figures(&l.name, stem, &l.log);
        out.figures.extend(figures);
        out.notes.extend(notes);
    }
    let vlogs: Vec<(&str, &str, &MeasurementLog)> = logs
        .iter()
        .zip(&stems)
        .filter(|(l, _)| has_validation(&l.log))
        .map(|(l, s)| (l.name.as_str(), s.as_str(), &l.log))
        .collect();
    if compare && vlogs.len() > 1 {
        let (figures, notes) = validation_figures(&vlogs, "validation");
        out.figures.extend(figures);
        out.notes.extend(notes);
    } else {
        for v in &vlogs {
            let (figures, notes) = validation_figures(std::slice::from_ref(v), v.1);
            out.figures.extend(figures);
            out.notes.extend(notes);
        }
    }
    for l in logs {
        if let Some(t) = &l.log.torn_tail {
            out.notes.push(format!(
                "{}: unterminated last line {} left out ({})",
                l.name, t.line, t.error
            ));
        }
    }
    Ok(out)
}

/// Writes the figures of [`figure_set`] into `out_dir` (created if
/// needed) as `<stem>.png` / `<stem>.svg`.
pub fn plot_logs(
    logs: &[NamedLog],
    out_dir: &Path,
    format: Format,
    compare: bool,
) -> Result<Plotted, PlotError> {
    let set = figure_set(logs, compare)?;
    ensure_dir(out_dir)?;
    let mut files = Vec::new();
    for f in &set.figures {
        files.extend(render_figure(&f.figure, &out_dir.join(&f.stem), format)?);
    }
    Ok(Plotted {
        files,
        notes: set.notes,
        figures: set.figures,
    })
}

/// Reads the logs at `paths` and writes every figure they support into
/// `out_dir`, each log's own (no comparison); returns the files written.
/// Notes (assumptions, points left out) go to `tracing` at warn level — use
/// [`read_logs`] + [`plot_logs`] to get them as data.
pub fn write_all<P: AsRef<Path>>(
    paths: &[P],
    out_dir: &Path,
    format: Format,
) -> Result<Vec<PathBuf>, PlotError> {
    let logs = read_logs(paths)?;
    let p = plot_logs(&logs, out_dir, format, false)?;
    for n in &p.notes {
        tracing::warn!("plot: {n}");
    }
    Ok(p.files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::charact::log::parse_bytes;
    use crate::model::Direction;
    use crate::plot::charact::{repeatability, scans as log_scans};
    use crate::plot::figure::Figure;
    use crate::plot::validation::{gather, BAR_AP_MAX, BAR_AP_MEAN, BAR_RP_MAX};
    use std::fmt::Write as _;

    const HEADER: &str =
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um";

    /// Deterministic small "noise" in [-0.5, 0.5).
    fn jitter(i: usize) -> f64 {
        ((i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as f64 / (1u64 << 24) as f64 - 0.5
    }

    /// A two-axis characterization: leadscrew-like cyclic error, ±1 µm
    /// backlash, coupling, 2 cycles, 100 µm steps.
    fn charact_log() -> String {
        let mut s = format!("# format: micropos-measurement-log/1\n{HEADER}\n");
        let mut i = 0;
        let mut t = 0.0;
        for (seg, axis) in [("scan_x", 0), ("scan_y", 1)] {
            for cycle in 0..2 {
                let fwd: Vec<f64> = (0..=20).map(|k| 100.0 * k as f64).collect();
                let bwd: Vec<f64> = fwd.iter().rev().copied().collect();
                for (dir, pass) in [(1.0, fwd), (-1.0, bwd)] {
                    for p in pass {
                        let along = 3.0 * (std::f64::consts::TAU * p / 400.0).sin()
                            + dir
                            + 0.05 * jitter(i);
                        let across =
                            0.5 * (std::f64::consts::TAU * p / 400.0).cos() + 0.05 * jitter(i + 7);
                        // error = target − meas → meas = target − error
                        let (xt, yt) = if axis == 0 { (p, 0.0) } else { (0.0, p) };
                        let (ex, ey) = if axis == 0 {
                            (along, across)
                        } else {
                            (across, along)
                        };
                        writeln!(
                            s,
                            "{t:.3},{seg},{cycle},{xt},{yt},{xt},{yt},{:.4},{:.4}",
                            xt - ex,
                            yt - ey
                        )
                        .unwrap();
                        i += 1;
                        t += 1.0;
                    }
                }
            }
        }
        s
    }

    /// Square and random validation with mode and pose columns: mode `m`
    /// has a constant error of `offset[m]` µm in x (AP known exactly) plus
    /// a ±`spread` alternation over cycles in y.
    fn validation_log() -> String {
        let mut s = format!("{HEADER},mode,pose\n");
        let modes = [
            ("raw", 20.0),
            ("table", 0.8),
            ("model", 0.5),
            ("closed_loop", 0.05),
        ];
        let square: Vec<(f64, f64)> = (0..8)
            .map(|k| (10.0 + 1000.0 * k as f64, 10.0))
            .chain((0..8).map(|k| (4010.0, 10.0 + 500.0 * k as f64)))
            .collect();
        let random = crate::charact::scan::RANDOM_TARGETS_UM;
        for (seg, poses) in [("square", square.as_slice()), ("random", &random[..])] {
            for (mode, off) in modes {
                for cycle in 0..3 {
                    let spread = if cycle % 2 == 0 { 0.01 } else { -0.01 };
                    for (pose, (x, y)) in poses.iter().enumerate() {
                        writeln!(
                            s,
                            "0,{seg},{cycle},{x},{y},{x},{y},{:.4},{:.4},{mode},{pose}",
                            x + off,
                            y + spread
                        )
                        .unwrap();
                    }
                }
            }
        }
        s
    }

    /// A random-points run by another program: no mode or pose column.
    fn foreign_validation_log() -> String {
        let mut s = format!("{HEADER}\n");
        for cycle in 0..2 {
            for (x, y) in crate::charact::scan::RANDOM_TARGETS_UM {
                writeln!(s, "0,random,{cycle},{x},{y},{x},{y},{x},{:.4}", y - 3.0).unwrap();
            }
        }
        s
    }

    fn named(name: &str, text: &str) -> NamedLog {
        NamedLog {
            name: format!("{name}.csv"),
            stem: name.into(),
            log: parse_bytes(text.as_bytes()).unwrap(),
        }
    }

    fn check_png(p: &Path, w: u32, h: u32) {
        let bytes = std::fs::read(p).unwrap();
        let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert_eq!((img.width(), img.height()), (w, h), "{}", p.display());
    }

    fn check_svg(p: &Path, needles: &[&str]) {
        let s = std::fs::read_to_string(p).unwrap();
        assert!(s.contains("<svg"), "{}", p.display());
        for n in needles {
            assert!(s.contains(n), "{}: no {n:?}", p.display());
        }
    }

    #[test]
    fn characterization_figures_are_written_with_units() {
        let dir = tempfile::tempdir().unwrap();
        let logs = [named("charact", &charact_log())];
        let p = plot_logs(&logs, dir.path(), Format::Both, false).unwrap();
        assert_eq!(p.files.len(), 6, "{:?}", p.files);
        assert!(p.notes.is_empty(), "{:?}", p.notes);
        for fig in ["fig4_errors", "fig5_coupling", "fig6_repeatability"] {
            let stem = dir.path().join(format!("charact_{fig}"));
            check_png(&stem.with_extension("png"), 1200, 2 * 420 + 40);
            check_svg(
                &stem.with_extension("svg"),
                &[
                    "x target (µm)",
                    "y target (µm)",
                    "charact.csv",
                    "forward",
                    "backward",
                ],
            );
        }
        check_svg(
            &dir.path().join("charact_fig4_errors.svg"),
            &[
                "x error, target − measured (µm)",
                "y error, target − measured (µm)",
            ],
        );
        check_svg(
            &dir.path().join("charact_fig5_coupling.svg"),
            &[
                "coupling error in y while x moves",
                "x error, target − measured (µm)",
            ],
        );
        check_svg(&dir.path().join("charact_fig6_repeatability.svg"), &["RP"]);
    }

    #[test]
    fn scans_split_into_directions_and_repeatability_is_iso9283() {
        let log = parse_bytes(charact_log().as_bytes()).unwrap();
        let [Some(x), Some(y)] = log_scans(&log) else {
            panic!("both scans expected")
        };
        // 2 cycles × 2 passes × 21 points, every direction told.
        assert_eq!((x.points.len(), x.undetermined), (84, 0));
        assert_eq!(y.points.len(), 84);
        // Forward points carry +1 µm of backlash, backward −1 µm.
        for p in &x.points {
            let cyclic = 3.0 * (std::f64::consts::TAU * p.target_um / 400.0).sin();
            let want = if p.direction == Direction::Forward {
                1.0
            } else {
                -1.0
            };
            assert!((p.along_um - cyclic - want).abs() < 0.03, "{p:?}");
        }
        // RP from two visits: l1 = l2 = d/2 → RP = d/2 (S = 0).
        let [f, b] = repeatability(&x);
        assert_eq!((f.len(), b.len()), (21, 21));
        let p = x
            .points
            .iter()
            .filter(|p| p.direction == Direction::Forward && p.target_um == 300.0)
            .collect::<Vec<_>>();
        let d = (p[0].meas.x_um - p[1].meas.x_um).hypot(p[0].meas.y_um - p[1].meas.y_um);
        let rp = f.iter().find(|(t, _)| *t == 300.0).unwrap().1;
        assert!((rp - d / 2.0).abs() < 1e-9, "{rp} vs {d}");
    }

    /// Table mode validated again in another log (a drift comparison) with
    /// a larger offset and spread.
    fn drift_comparison_log() -> String {
        let mut s = format!("{HEADER},mode,pose\n");
        for cycle in 0..3 {
            let spread = if cycle % 2 == 0 { 0.5 } else { -0.5 };
            for (pose, (x, y)) in crate::charact::scan::RANDOM_TARGETS_UM.iter().enumerate() {
                writeln!(
                    s,
                    "0,random,{cycle},{x},{y},{x},{y},{:.4},{:.4},table,{pose}",
                    x + 3.0,
                    y + spread
                )
                .unwrap();
            }
        }
        s
    }

    /// AP max, AP mean and RP max of one mode of one log, straight from its
    /// records (ISO 9283 per pose, then max/mean), as `validate` computes
    /// them: what the log's own run printed.
    fn own_summary(log: &MeasurementLog, segment: &str, mode: &str) -> (f64, f64, Option<f64>) {
        use crate::metrology::{pose_stats, summarize_poses, Xy};
        let mode_col = log.columns.extra.iter().position(|c| c == "mode").unwrap();
        let mut by_target: Vec<(Xy, Vec<Xy>)> = Vec::new();
        for r in log
            .records
            .iter()
            .filter(|r| r.segment == segment && r.extra[mode_col] == mode)
        {
            let t = Xy::new(r.x_target_um, r.y_target_um);
            let m = Xy::new(r.x_meas_um, r.y_meas_um);
            match by_target.iter_mut().find(|(u, _)| *u == t) {
                Some((_, v)) => v.push(m),
                None => by_target.push((t, vec![m])),
            }
        }
        let stats: Vec<_> = by_target
            .iter()
            .map(|(t, v)| pose_stats(*t, v).unwrap())
            .collect();
        let s = summarize_poses(&stats).unwrap();
        (s.ap_max_um, s.ap_mean_um, s.rp_max_um)
    }

    /// The bars of a validation figure: category → (AP max, AP mean, RP max).
    fn bars(f: &Figure) -> Vec<(String, [Option<f64>; 3])> {
        let Some(crate::plot::figure::Panel::Bars(b)) = f.rows.last().and_then(|r| r.first())
        else {
            panic!("a bar panel last: {f:?}")
        };
        let col = |label: &str| {
            b.groups
                .iter()
                .find(|g| g.label == label)
                .unwrap_or_else(|| panic!("no {label} bars"))
        };
        let (a, m, r) = (col(BAR_AP_MAX), col(BAR_AP_MEAN), col(BAR_RP_MAX));
        b.categories
            .iter()
            .enumerate()
            .map(|(i, c)| (c.clone(), [a.values[i], m.values[i], r.values[i]]))
            .collect()
    }

    /// Two logs carrying mode `table` (a validation and its drift
    /// comparison): by default each is a figure of its own, and the
    /// validation's figure shows exactly the AP and RP of its own records;
    /// compared, they are two series, labelled per log, never one.
    #[test]
    fn each_validation_log_is_a_figure_of_its_own_unless_compared() {
        let dir = tempfile::tempdir().unwrap();
        let logs = [
            named("validate", &validation_log()),
            named("validate-drift-off", &drift_comparison_log()),
        ];
        let p = plot_logs(&logs, dir.path(), Format::Svg, false).unwrap();
        let stems: Vec<&str> = p.figures.iter().map(|f| f.stem.as_str()).collect();
        assert_eq!(
            stems,
            [
                "validate_fig10_square",
                "validate_fig11_random",
                "validate-drift-off_fig11_random"
            ]
        );
        assert_eq!(p.files.len(), 3);
        let own = &p.figures[1].figure;
        assert!(own.title.contains("validate.csv"), "{}", own.title);
        assert!(!own.title.contains("validate-drift-off"), "{}", own.title);
        let b = bars(own);
        let cats: Vec<&str> = b.iter().map(|(c, _)| c.as_str()).collect();
        assert_eq!(cats, ["raw", "table", "model", "closed_loop"]);
        for (mode, [ap, mean, rp]) in &b {
            let (want_ap, want_mean, want_rp) = own_summary(&logs[0].log, "random", mode);
            assert!(
                (ap.unwrap() - want_ap).abs() < 1e-12,
                "{mode}: AP {ap:?} vs {want_ap}"
            );
            assert!((mean.unwrap() - want_mean).abs() < 1e-12, "{mode}");
            assert!(
                (rp.unwrap() - want_rp.unwrap()).abs() < 1e-12,
                "{mode}: RP {rp:?} vs {want_rp:?}"
            );
        }
        // The table bars: the validation's own 0.8 µm, RP of ±0.01 µm
        // spread, not the comparison's 3 µm and ±0.5 µm.
        let table = b[1].1;
        assert!((table[0].unwrap() - 0.8).abs() < 1e-3, "{table:?}");
        assert!(table[2].unwrap() < 0.1, "{table:?}");
        // The comparison log's figure: its own table mode.
        let drift = bars(&p.figures[2].figure);
        assert_eq!(drift.len(), 1);
        let (want_ap, _, want_rp) = own_summary(&logs[1].log, "random", "table");
        assert!(
            (drift[0].1[0].unwrap() - want_ap).abs() < 1e-12,
            "{drift:?}"
        );
        assert!((drift[0].1[2].unwrap() - want_rp.unwrap()).abs() < 1e-12);
        assert!((want_ap - 3.0).abs() < 0.01);

        // Asked to compare: one figure per trajectory, two table series.
        let p = plot_logs(&logs, dir.path(), Format::Svg, true).unwrap();
        let random = p
            .figures
            .iter()
            .find(|f| f.stem == "validation_fig11_random")
            .unwrap();
        let b = bars(&random.figure);
        let cats: Vec<&str> = b.iter().map(|(c, _)| c.as_str()).collect();
        assert_eq!(
            cats,
            [
                "raw (validate.csv)",
                "table (validate.csv)",
                "table (validate-drift-off.csv)",
                "model (validate.csv)",
                "closed_loop (validate.csv)"
            ]
        );
        assert!((b[1].1[0].unwrap() - 0.8).abs() < 1e-3);
        assert!((b[2].1[0].unwrap() - want_ap).abs() < 1e-12);
        // Two runs' logs of one name (two directories): two series too.
        let runs = [
            named("validate", &validation_log()),
            named("validate", &drift_comparison_log()),
        ];
        let dir2 = tempfile::tempdir().unwrap();
        let p = plot_logs(&runs, dir2.path(), Format::Svg, true).unwrap();
        let random = p
            .figures
            .iter()
            .find(|f| f.stem == "validation_fig11_random")
            .unwrap();
        let b = bars(&random.figure);
        let tables: Vec<_> = b.iter().filter(|(c, _)| c.starts_with("table")).collect();
        assert_eq!(tables.len(), 2, "{b:?}");
        assert_eq!(tables[0].0, "table (validate)");
        assert_eq!(tables[1].0, "table (validate_2)");
        assert!((tables[0].1[0].unwrap() - 0.8).abs() < 1e-3);
        assert!((tables[1].1[0].unwrap() - want_ap).abs() < 1e-12);
        let svg = std::fs::read_to_string(dir.path().join("validation_fig11_random.svg")).unwrap();
        assert!(svg.contains("table (validate-drift-off.csv)"));
    }

    #[test]
    fn compared_validation_logs_keep_modes_and_files_apart() {
        let dir = tempfile::tempdir().unwrap();
        let logs = [
            named("valid", &validation_log()),
            named("other_prog", &foreign_validation_log()),
        ];
        let p = plot_logs(&logs, dir.path(), Format::Both, true).unwrap();
        assert_eq!(p.files.len(), 4, "{:?}", p.files);
        assert!(
            p.notes
                .iter()
                .any(|n| n.contains("other_prog.csv") && n.contains("no `mode` column")),
            "{:?}",
            p.notes
        );
        let sq = dir.path().join("validation_fig10_square");
        check_png(&sq.with_extension("png"), 1400, 1500);
        check_svg(
            &sq.with_extension("svg"),
            &[
                "x (µm)",
                "AP (µm)",
                "x_meas − x_target (µm)",
                "raw",
                "closed_loop",
                "valid.csv",
            ],
        );
        // Only valid.csv has square records: its series need no log name.
        let svg = std::fs::read_to_string(sq.with_extension("svg")).unwrap();
        assert!(!svg.contains("raw (valid.csv)"));
        let rnd = dir.path().join("validation_fig11_random");
        check_png(&rnd.with_extension("png"), 1400, 1500);
        check_svg(
            &rnd.with_extension("svg"),
            &[
                "raw (valid.csv)",
                "closed_loop (valid.csv)",
                "other_prog (other_prog.csv)",
                "Fig. 11",
                "log scale",
            ],
        );
        // AP per mode is the known constant offset; the foreign file is a
        // mode of its own with AP 3 µm.
        let refs: Vec<(&str, &str, &MeasurementLog)> = logs
            .iter()
            .map(|l| (l.name.as_str(), l.stem.as_str(), &l.log))
            .collect();
        let (sets, _) = gather(&refs);
        assert_eq!(sets.len(), 2);
        let random = &sets[1];
        assert_eq!(random.poses.len(), 10);
        let names: Vec<&str> = random.modes.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(
            names,
            ["raw", "table", "model", "closed_loop", "other_prog"]
        );
        for (m, want) in random.modes.iter().zip([20.0, 0.8, 0.5, 0.05, 3.0]) {
            let s = m.summary(&random.poses).unwrap();
            assert!(
                (s.ap_max_um - want).abs() < 1e-3,
                "{}: {}",
                m.name,
                s.ap_max_um
            );
        }
        let square = &sets[0];
        assert_eq!(square.poses.len(), 16);
        assert_eq!(square.poses[9].label.as_deref(), Some("9"));
        // Every text of the figures on the canvas.
        for f in [&sq, &rnd] {
            let svg = std::fs::read_to_string(f.with_extension("svg")).unwrap();
            let off = crate::plot::svg_check::texts_off_canvas(&svg);
            assert!(off.is_empty(), "{}: {off:#?}", f.display());
        }
    }

    #[test]
    fn format_selects_files_and_bad_input_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let logs = [named("c", &charact_log())];
        let p = plot_logs(&logs, dir.path(), Format::Svg, false).unwrap();
        assert!(p.files.iter().all(|f| f.extension().unwrap() == "svg"));
        assert_eq!(p.files.len(), 3);
        // Nothing plottable: refused, naming the log and what it holds.
        let other = named("o", &format!("{HEADER}\n0,warmup,0,0,0,0,0,0,0\n"));
        let e = plot_logs(&[other], dir.path(), Format::Png, false).unwrap_err();
        assert!(
            e.to_string().contains("o.csv") && e.to_string().contains("warmup"),
            "{e}"
        );
        assert!(plot_logs(&[], dir.path(), Format::Png, false).is_err());
        // Unreadable logs: missing file, malformed content.
        let bad = dir.path().join("bad.csv");
        std::fs::write(&bad, format!("{HEADER}\n0,scan_x,0,abc,0,0,0,0,0\n")).unwrap();
        let e = write_all(std::slice::from_ref(&bad), dir.path(), Format::Png).unwrap_err();
        assert!(
            e.to_string().contains("bad.csv") && e.to_string().contains("line 2"),
            "{e}"
        );
        let e = write_all(&[dir.path().join("missing.csv")], dir.path(), Format::Png).unwrap_err();
        assert!(e.to_string().contains("missing.csv"), "{e}");
        // Same stem twice: both kept.
        let two = [named("c", &charact_log()), named("c", &charact_log())];
        let p = plot_logs(&two, dir.path(), Format::Png, false).unwrap();
        assert!(p.files.iter().any(|f| f.ends_with("c_2_fig4_errors.png")));
    }
}
