//! The plots of `micropos diagnose --plots DIR`: residuals against every
//! variable of the log (after the parameter corrections, and after the
//! findings too), periodograms of those residuals against each position
//! and time, and the parameter corrections themselves (fitted − model, in
//! standard errors).
//!
//! Only what the log measured is drawn: no residual of an unmeasured
//! component, no variable that does not vary in the log (the placeholder
//! position of a 1-D log's other axis).

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
    if !d.parameters.is_empty() {
        files.extend(render(
            &corrections_chart(d),
            &dir.join("parameter_corrections"),
        )?);
    }
    let varies = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        hi > lo
    };
    let measured = |c: usize| d.measured_axes.iter().any(|a| a.index() == c);
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
    vars.retain(|(_, _, v)| varies(v));
    for (c, comp) in ["x", "y"].iter().enumerate() {
        if !measured(c) {
            continue;
        }
        // Visits left out as outliers have no fitted residual (they are
        // zero after the centring): not drawn, and the legend says so.
        let kept = |v: &[f64]| -> Vec<(f64, f64)> {
            pairs(v, &s.before_um[c])
                .into_iter()
                .zip(&s.excluded)
                .filter(|(_, &e)| !e)
                .map(|(p, _)| p)
                .collect()
        };
        let kept_after = |v: &[f64]| -> Vec<(f64, f64)> {
            pairs(v, &s.after_um[c])
                .into_iter()
                .zip(&s.excluded)
                .filter(|(_, &e)| !e)
                .map(|(p, _)| p)
                .collect()
        };
        let left_out = s.excluded.iter().filter(|&&e| e).count();
        let note = if left_out > 0 {
            format!(" ({left_out} outlier visit(s) left out, see the report)")
        } else {
            String::new()
        };
        for (name, label, v) in &vars {
            let chart = Chart {
                title: format!("{comp} residual (measured − model) vs {name}{note}"),
                x_label: label.clone(),
                y_label: format!("{comp} residual (µm)"),
                series: vec![
                    Series {
                        label: "parameter corrections (base fit)".into(),
                        points: kept(v),
                        mark: Mark::Dots,
                    },
                    Series {
                        label: "corrections + findings (extended model)".into(),
                        points: kept_after(v),
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
            if span.is_nan() || span <= 0.0 || (name != "time" && !varies(v)) {
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
            "residual before/after the findings: {} (in-sample rms)",
            (0..2)
                .filter(|&c| measured(c))
                .map(|c| format!(
                    "{} {:.3}→{:.3} µm",
                    ["x", "y"][c],
                    rms(&s.before_um[c]),
                    rms(&s.after_um[c])
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        x_label: "point index".into(),
        y_label: "residual (µm)".into(),
        series: (0..2)
            .filter(|&c| measured(c))
            .flat_map(|c| {
                let comp = ["x", "y"][c];
                [
                    Series {
                        label: format!("{comp} after parameter corrections"),
                        points: s.before_um[c]
                            .iter()
                            .enumerate()
                            .map(|(i, v)| (i as f64, *v))
                            .collect(),
                        mark: Mark::Dots,
                    },
                    Series {
                        label: format!("{comp} after corrections + findings"),
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
    if let Some(g) = &d.grid {
        for (c, m) in g.components.iter().enumerate() {
            let comp = &m.component;
            files.extend(render(
                &separable_chart(g, c),
                &dir.join(format!("grid_separable_{comp}")),
            )?);
            files.extend(render(
                &joint_chart(g, c),
                &dir.join(format!("grid_joint_{comp}")),
            )?);
        }
    }
    Ok(files)
}

/// A map's separable part of component `c`: `f(x)` and `g(y)` after the
/// plane (e = measured − target).
fn separable_chart(g: &crate::analysis::grid::GridReport, c: usize) -> Chart {
    let m = &g.components[c];
    let comp = &m.component;
    Chart {
        title: format!("grid map: separable part of e{comp} after the plane (f(x) and g(y))"),
        x_label: "position along the axis (µm)".into(),
        y_label: format!("e{comp} = measured − target (µm)"),
        series: vec![
            Series {
                label: format!("f(x): e{comp} along x"),
                points: pairs(&g.xs_um, &m.f_um),
                mark: Mark::Line,
            },
            Series {
                label: format!("g(y): e{comp} along y"),
                points: pairs(&g.ys_um, &m.g_um),
                mark: Mark::Line,
            },
        ],
    }
}

/// A map's joint x–y part of component `c` (what no `f(x) + g(y)`
/// holds) along x, for up to six rows spread over y: the map as profiles.
fn joint_chart(g: &crate::analysis::grid::GridReport, c: usize) -> Chart {
    let m = &g.components[c];
    let comp = &m.component;
    let (xs, ys) = (&g.xs_um, &g.ys_um);
    let rows = ys.len();
    let picks: Vec<usize> = if rows <= 6 {
        (0..rows).collect()
    } else {
        (0..6).map(|k| k * (rows - 1) / 5).collect()
    };
    Chart {
        title: format!(
            "grid map: joint x–y part of e{comp} ({:.3} µm rms; {})",
            m.separable_rms_um,
            if m.non_separable.is_some() {
                "a finding"
            } else {
                "not a finding"
            }
        ),
        x_label: "commanded x (µm)".into(),
        y_label: format!("e{comp} − plane − f(x) − g(y) (µm)"),
        series: picks
            .into_iter()
            .map(|iy| Series {
                label: format!("y = {:.0} µm", ys[iy]),
                points: (0..xs.len())
                    .filter_map(|ix| m.interaction_um[iy * xs.len() + ix].map(|v| (xs[ix], v)))
                    .collect(),
                mark: Mark::Line,
            })
            .collect(),
    }
}

/// The parameter corrections: `(fitted − model)/σ` per identified
/// parameter, the ones beyond the significance line apart; the title names
/// the largest.
fn corrections_chart(d: &Diagnosis) -> Chart {
    let z = |p: &crate::analysis::diagnose::ParamCorrection| {
        let dz = (p.fitted_value - p.model_value) / p.std_error;
        if dz.is_finite() {
            dz
        } else {
            0.0
        }
    };
    let mut sig = Vec::new();
    let mut agree = Vec::new();
    for (i, p) in d.parameters.iter().enumerate() {
        let pt = (i as f64, z(p));
        if p.significant {
            sig.push(pt);
        } else {
            agree.push(pt);
        }
    }
    let mut top: Vec<&crate::analysis::diagnose::ParamCorrection> =
        d.parameters.iter().filter(|p| p.significant).collect();
    top.sort_by(|a, b| z(b).abs().total_cmp(&z(a).abs()));
    let names = top
        .iter()
        .take(3)
        .map(|p| format!("{}.{}", p.term, p.parameter))
        .collect::<Vec<_>>()
        .join(", ");
    Chart {
        title: format!(
            "parameter corrections: {} of {} differ from the model{}",
            top.len(),
            d.parameters.len(),
            if names.is_empty() {
                String::new()
            } else {
                format!(" (largest: {names})")
            }
        ),
        x_label: "identified parameter (order of the JSON `parameters`)".into(),
        y_label: "(fitted − model) / σ".into(),
        series: vec![
            Series {
                label: format!(
                    "|fitted − model| ≥ {} σ",
                    crate::analysis::diagnose::SIGNIFICANT_SIGMAS
                ),
                points: sig,
                mark: Mark::Dots,
            },
            Series {
                label: "agrees with the model".into(),
                points: agree,
                mark: Mark::Dots,
            },
        ],
    }
}
