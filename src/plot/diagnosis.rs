//! The plots of `micropos diagnose --plots DIR`: residuals against every
//! variable of the log (before and after the extension), periodograms of
//! the base residuals against each position and time.

use std::path::{Path, PathBuf};

use super::{ensure_dir, render, Chart, Mark, PlotError, Series};
use crate::analysis::diagnose::Diagnosis;
use crate::analysis::periodogram::gls_grid;

fn pairs(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    x.iter().copied().zip(y.iter().copied()).collect()
}

/// Writes every diagnose plot into `dir`; returns the files written.
pub fn write_all(d: &Diagnosis, dir: &Path) -> Result<Vec<PathBuf>, PlotError> {
    ensure_dir(dir)?;
    let s = &d.series;
    let mut files = Vec::new();
    let mut vars: Vec<(String, String, &[f64])> = vec![
        ("x".into(), "commanded x (µm)".into(), &s.x_um),
        ("y".into(), "commanded y (µm)".into(), &s.y_um),
        ("time".into(), "time (s)".into(), &s.t_s),
        ("temperature".into(), "temperature (°C)".into(), &s.temp_c),
        (
            "xdir".into(),
            "direction of x motion (−1 backward, +1 forward)".into(),
            &s.x_dir,
        ),
        (
            "ydir".into(),
            "direction of y motion (−1 backward, +1 forward)".into(),
            &s.y_dir,
        ),
        (
            "xmove".into(),
            "length of the last x move (µm)".into(),
            &s.x_last_move_um,
        ),
        (
            "ymove".into(),
            "length of the last y move (µm)".into(),
            &s.y_last_move_um,
        ),
    ];
    for (name, v) in &s.extra {
        // File names from a log's column name: keep it to safe characters.
        let safe: String = name
            .chars()
            .map(|ch| {
                if ch.is_ascii_alphanumeric() || ch == '_' || ch == '-' {
                    ch
                } else {
                    '_'
                }
            })
            .take(60)
            .collect();
        vars.push((format!("col_{safe}"), format!("log column `{name}`"), v));
    }
    for (c, comp) in ["x", "y"].iter().enumerate() {
        for (name, label, v) in &vars {
            let chart = Chart {
                title: format!("{comp} residual (measured − model) vs {name}"),
                x_label: label.clone(),
                y_label: format!("{comp} residual (µm)"),
                series: vec![
                    Series {
                        label: "base fit".into(),
                        points: pairs(v, &s.before_um[c]),
                        mark: Mark::Dots,
                    },
                    Series {
                        label: "extended model".into(),
                        points: pairs(v, &s.after_um[c]),
                        mark: Mark::Dots,
                    },
                ],
            };
            files.extend(render(
                &chart,
                &dir.join(format!("residual_{comp}_vs_{name}")),
            )?);
        }
        for (name, label, v, unit) in [
            ("x", "period (µm of x)", &s.x_um, "µm"),
            ("y", "period (µm of y)", &s.y_um, "µm"),
            ("time", "period (s)", &s.t_s, "s"),
        ] {
            let (lo, hi) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            let span = hi - lo;
            if span.is_nan() || span <= 0.0 {
                continue;
            }
            let f_min = 2.0 / span;
            let f_max = 50.0 / span.min(1e12);
            let n = 600;
            let df = (f_max - f_min) / n as f64;
            let mut series = Vec::new();
            for (label, r) in [
                ("base fit", &s.before_um[c]),
                ("extended model", &s.after_um[c]),
            ] {
                let p = gls_grid(v, r, f_min, df, n);
                series.push(Series {
                    label: label.into(),
                    points: p
                        .iter()
                        .enumerate()
                        .map(|(k, pw)| (1.0 / (f_min + k as f64 * df), *pw))
                        .collect(),
                    mark: Mark::Line,
                });
            }
            let chart = Chart {
                title: format!("periodogram of the {comp} residual against {name} (GLS)"),
                x_label: format!("{label} [{unit}]"),
                y_label: "normalized power".into(),
                series,
            };
            files.extend(render(
                &chart,
                &dir.join(format!("periodogram_{comp}_vs_{name}")),
            )?);
        }
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let chart = Chart {
        title: format!(
            "residual before/after: x {:.3}→{:.3} µm, y {:.3}→{:.3} µm (in-sample rms)",
            rms(&s.before_um[0]),
            rms(&s.after_um[0]),
            rms(&s.before_um[1]),
            rms(&s.after_um[1])
        ),
        x_label: "point index".into(),
        y_label: "residual (µm)".into(),
        series: (0..2)
            .flat_map(|c| {
                let comp = ["x", "y"][c];
                [
                    Series {
                        label: format!("{comp} base fit"),
                        points: s.before_um[c]
                            .iter()
                            .enumerate()
                            .map(|(i, v)| (i as f64, *v))
                            .collect(),
                        mark: Mark::Dots,
                    },
                    Series {
                        label: format!("{comp} extended"),
                        points: s.after_um[c]
                            .iter()
                            .enumerate()
                            .map(|(i, v)| (i as f64, *v))
                            .collect(),
                        mark: Mark::Dots,
                    },
                ]
            })
            .collect(),
    };
    files.extend(render(&chart, &dir.join("before_after"))?);
    Ok(files)
}
