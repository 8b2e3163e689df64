//! The plots of `micropos diagnose --plots DIR`: residuals against every
//! variable of the log (after the parameter corrections, and after the
//! findings too), periodograms of those residuals against each position
//! and time, and the parameter corrections themselves (fitted − model, in
//! standard errors).
//!
//! When the log is a complete bidirectional test of an axis, its ISO 230-2
//! deviation chart comes first (`iso230_2_deviation_<axis>`): the mean
//! positional deviation per target of the forward (↑) and reverse (↓)
//! approaches with their ±2s bands, titled with E, M, B, A and R — the
//! figures `diagnose` prints first, from the same numbers. Deviation =
//! measured − target (ISO 230-2's `x_ij = P_ij − P_i`), the sign of the
//! printed figures; the axis label says so.
//!
//! Only what the log measured is drawn: no residual of an unmeasured
//! component, no variable that does not vary in the log (the placeholder
//! position of a 1-D log's other axis), no temperature the log did not
//! record (the model's assumed temperature history is not a
//! measurement), no time when the log's times are synthetic (record
//! order; `before_after` already shows it).

use std::path::{Path, PathBuf};

use super::figure::{render_figure, Figure, Format, Panel, Scale, Style, Trace, XyPanel};
use super::{ensure_dir, render, Chart, Mark, PlotError, Series};
use crate::analysis::diagnose::{Diagnosis, IsoFigures};
use crate::analysis::periodogram::gls_grid;
use crate::model::Axis;

/// ISO 230-2's positional deviation chart of axis `axis` from its figures:
/// per target `P_i`, the mean deviations `x̄↑_i` (positive approach) and
/// `x̄↓_i` (negative approach) with `x̄ ± 2s` bands (dashed), and the mean
/// bidirectional deviation `x̄_i`; the title states E, M, B (and the mean
/// reversal B̄), A and R. Labels spell out "mean" rather than x̄: the
/// font's combining macron does not sit on its letter. `None` without
/// per-target figures.
pub fn iso_deviation_figure(axis: Axis, iso: &IsoFigures) -> Option<Figure> {
    if iso.per_target.is_empty() {
        return None;
    }
    let a = axis.as_str();
    let t = &iso.per_target;
    let line = |f: &dyn Fn(&crate::metrology::iso230_2::TargetFigures) -> f64| -> Vec<(f64, f64)> {
        t.iter().map(|p| (p.target_um, f(p))).collect()
    };
    let traces = vec![
        Trace {
            label: Some("mean deviation, positive approach (↑)".into()),
            color: 0,
            points: line(&|p| p.mean_up_um),
            style: Style::LineDots,
        },
        Trace {
            label: Some("mean ↑ ± 2s↑".into()),
            color: 0,
            points: line(&|p| p.mean_up_um + 2.0 * p.s_up_um),
            style: Style::Dashed,
        },
        Trace {
            label: None,
            color: 0,
            points: line(&|p| p.mean_up_um - 2.0 * p.s_up_um),
            style: Style::Dashed,
        },
        Trace {
            label: Some("mean deviation, negative approach (↓)".into()),
            color: 1,
            points: line(&|p| p.mean_down_um),
            style: Style::LineDots,
        },
        Trace {
            label: Some("mean ↓ ± 2s↓".into()),
            color: 1,
            points: line(&|p| p.mean_down_um + 2.0 * p.s_down_um),
            style: Style::Dashed,
        },
        Trace {
            label: None,
            color: 1,
            points: line(&|p| p.mean_down_um - 2.0 * p.s_down_um),
            style: Style::Dashed,
        },
        Trace {
            label: Some("mean bidirectional deviation (↑ + ↓)/2".into()),
            color: 5,
            points: line(&|p| p.mean_um),
            style: Style::Line,
        },
    ];
    let few = if iso.cycles < crate::metrology::iso230_2::ISO_MIN_CYCLES {
        format!(
            "; {} cycles, fewer than the standard's {}",
            iso.cycles,
            crate::metrology::iso230_2::ISO_MIN_CYCLES
        )
    } else {
        format!("; {} cycles", iso.cycles)
    };
    let paired = iso.paired_within_um.map_or(String::new(), |w| {
        format!("; forward and backward arrivals up to {w:.1} µm apart, paired")
    });
    Some(Figure {
        title: format!(
            "ISO 230-2 positional deviation of {a}: E {:.3} µm, M {:.3} µm, B {:.3} µm (mean B {:+.3} µm), A {:.3} µm, R {:.3} µm — {} visits{few}{paired}",
            iso.e_um, iso.m_um, iso.b_um, iso.mean_b_um, iso.a_um, iso.r_um, iso.visits
        ),
        rows: vec![vec![Panel::Xy(XyPanel {
            title: "mean deviation per target and approach direction, with ± 2s bands".into(),
            x_label: format!("{a} target P_i (µm)"),
            y_label: "deviation = measured − target (µm)".into(),
            traces,
            y_scale: Scale::Linear,
            equal_aspect: false,
        })]],
        size: (1100, 650),
    })
}

/// Whether at least two finite values of `v` differ.
fn varies(v: &[f64]) -> bool {
    let (lo, hi) = v
        .iter()
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    hi > lo
}

fn pairs(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    x.iter().copied().zip(y.iter().copied()).collect()
}

/// Writes every diagnose plot into `dir`; returns the files written.
pub fn write_all(d: &Diagnosis, dir: &Path) -> Result<Vec<PathBuf>, PlotError> {
    ensure_dir(dir)?;
    let mut files = Vec::new();
    for c in &d.noise.components {
        if let Some(f) = c
            .iso230_2
            .as_ref()
            .and_then(|iso| iso_deviation_figure(c.component, iso))
        {
            files.extend(render_figure(
                &f,
                &dir.join(format!("iso230_2_deviation_{}", c.component.as_str())),
                Format::Both,
            )?);
        }
    }
    if !d.parameters.is_empty() {
        files.extend(render(
            &corrections_chart(d),
            &dir.join("parameter_corrections"),
        )?);
    }
    let vars = residual_variables(d);
    for (c, comp) in ["x", "y"].iter().enumerate() {
        if !measured(d, c) {
            continue;
        }
        files.extend(residual_charts(d, c, comp, &vars, dir)?);
        files.extend(periodograms(d, c, comp, dir)?);
    }
    let chart = before_after_chart(d);
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

/// Whether the diagnosis measured component `c`: only those are drawn.
fn measured(d: &Diagnosis, c: usize) -> bool {
    d.measured_axes.iter().any(|a| a.index() == c)
}

/// The variables the residuals are drawn against, as (file name part,
/// axis label, values): those that vary over the log.
fn residual_variables(d: &Diagnosis) -> Vec<(String, String, &[f64])> {
    let s = &d.series;
    let mut vars: Vec<(String, String, &[f64])> = vec![
        ("x".into(), "commanded x (µm)".into(), &s.x_um),
        ("y".into(), "commanded y (µm)".into(), &s.y_um),
        ("time".into(), "time (s)".into(), &s.t_s),
        (
            "temperature".into(),
            "temperature, as logged (°C)".into(),
            &s.temp_c,
        ),
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
    // Synthetic times are the record order: not a quantity of the log.
    vars.retain(|(name, _, v)| varies(v) && !(d.synthetic_time && name == "time"));
    vars
}

/// The residual of component `c` (`comp`) against each of `vars`,
/// before and after the findings.
fn residual_charts(
    d: &Diagnosis,
    c: usize,
    comp: &str,
    vars: &[(String, String, &[f64])],
    dir: &Path,
) -> Result<Vec<PathBuf>, PlotError> {
    let s = &d.series;
    let mut files = Vec::new();
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
    for (name, label, v) in vars {
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
    Ok(files)
}

/// Periodograms of the residual of component `c` (`comp`) against the
/// positions and time, before and after the findings.
fn periodograms(
    d: &Diagnosis,
    c: usize,
    comp: &str,
    dir: &Path,
) -> Result<Vec<PathBuf>, PlotError> {
    let s = &d.series;
    let mut files = Vec::new();
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
        if span.is_nan()
            || span <= 0.0
            || (name != "time" && !varies(v))
            || (name == "time" && d.synthetic_time)
        {
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
    Ok(files)
}

/// The residual at each point before and after the findings.
fn before_after_chart(d: &Diagnosis) -> Chart {
    let s = &d.series;
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    Chart {
        title: format!(
            "residual before/after the findings: {} (in-sample rms)",
            (0..2)
                .filter(|&c| measured(d, c))
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
            .filter(|&c| measured(d, c))
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
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::diagnose::{diagnose, DiagnoseOptions};
    use crate::charact::log::parse_bytes;
    use crate::model::StageModel;
    use std::fmt::Write as _;

    /// A play and a lead error: the model a user writes for a leadscrew
    /// axis.
    const AXIS_MODEL: &str = r#"
format_version = 1
[[term]]
kind = "backlash"
name = "x_backlash"
axis = "x"
backlash_um = 2.0

[[term]]
kind = "lead_error"
name = "x_lead"
axis = "x"
ppm = 0.0
"#;

    /// Deterministic small "noise" in [-0.5, 0.5).
    fn jitter(i: usize) -> f64 {
        ((i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as f64 / (1u64 << 24) as f64 - 0.5
    }

    /// An ISO 230-2 test of x: 5 targets, 5 cycles, each target reached
    /// `fwd_um` beyond it forward and `bwd_um` backward (measured −
    /// target), ± 0.1 µm. `temp`: the `temp_c` cell per record (`None`: no
    /// column); `synthetic`: times declared synthetic.
    fn iso_log(
        fwd_um: f64,
        bwd_um: f64,
        temp: Option<&dyn Fn(usize) -> String>,
        synthetic: bool,
    ) -> String {
        let mut s = String::from("# format: micropos-measurement-log/1\n");
        if synthetic {
            s += "# time_source: synthetic: record order, 1 s per point\n";
        }
        s += "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um";
        if temp.is_some() {
            s += ",temp_c";
        }
        s += ",approach\n";
        let targets: Vec<f64> = (0..5).map(|k| 1000.0 + 2500.0 * k as f64).collect();
        let mut i = 0;
        for cycle in 1..=5u32 {
            for (dev, ap, order) in [
                (fwd_um, "fwd", targets.clone()),
                (bwd_um, "bwd", targets.iter().rev().copied().collect()),
            ] {
                for x in order {
                    let m = x + dev + 0.2 * jitter(i);
                    write!(s, "{},scan_x,{cycle},{x},0,{x},0,{m:.4},0", 30 * i).unwrap();
                    if let Some(t) = temp {
                        write!(s, ",{}", t(i)).unwrap();
                    }
                    writeln!(s, ",{ap}").unwrap();
                    i += 1;
                }
            }
        }
        s
    }

    fn diagnosed(text: &str) -> Diagnosis {
        let log = parse_bytes(text.as_bytes()).unwrap();
        let model = StageModel::from_toml(AXIS_MODEL).unwrap();
        diagnose(&log, &model, &DiagnoseOptions::default()).unwrap()
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// The deviation chart of an ISO 230-2 test: forward arrivals 2 µm
    /// beyond their targets plot at +2 µm (measured − target, the printed
    /// figures' sign), backward 1 µm short at −1 µm; the title carries the
    /// figures the report prints.
    #[test]
    fn iso_deviation_chart_is_measured_minus_target_with_the_printed_figures() {
        let d = diagnosed(&iso_log(2.0, -1.0, None, false));
        let c = d
            .noise
            .components
            .iter()
            .find(|c| c.component == Axis::X)
            .unwrap();
        let iso = c.iso230_2.as_ref().expect("a complete bidirectional test");
        assert!((iso.mean_b_um - 3.0).abs() < 0.1, "B̄ {}", iso.mean_b_um);
        let fig = iso_deviation_figure(Axis::X, iso).unwrap();
        let Panel::Xy(p) = &fig.rows[0][0] else {
            panic!("an x–y panel")
        };
        assert_eq!(p.y_label, "deviation = measured − target (µm)");
        let trace = |prefix: &str| {
            p.traces
                .iter()
                .find(|t| t.label.as_deref().is_some_and(|l| l.starts_with(prefix)))
                .unwrap_or_else(|| panic!("no {prefix} trace"))
        };
        let (up, down) = (
            trace("mean deviation, positive"),
            trace("mean deviation, negative"),
        );
        assert_eq!(up.points.len(), 5);
        for (&(t, u), &(_, dn)) in up.points.iter().zip(&down.points) {
            assert!((u - 2.0).abs() < 0.1, "forward at {t}: {u}");
            assert!((dn + 1.0).abs() < 0.1, "backward at {t}: {dn}");
        }
        // ± 2s bands around each mean.
        let band = trace("mean ↑ ± 2s↑");
        for (b, (pt, m)) in band
            .points
            .iter()
            .zip(iso.per_target.iter().zip(&up.points))
        {
            assert!((b.1 - (m.1 + 2.0 * pt.s_up_um)).abs() < 1e-12);
        }
        // The title states E, M, B, A, R as the report prints them (B̄
        // with its sign: forward − backward, measured − target).
        for (k, v) in [
            ("E", iso.e_um),
            ("M", iso.m_um),
            ("B", iso.b_um),
            ("A", iso.a_um),
            ("R", iso.r_um),
        ] {
            let want = format!("{k} {v:.3} µm");
            assert!(fig.title.contains(&want), "{want} in {}", fig.title);
        }
        assert!(fig
            .title
            .contains(&format!("mean B {:+.3} µm", iso.mean_b_um)));
        assert!(d.to_text().contains(&format!("B̄ {:+.4} µm", iso.mean_b_um)));
        let dir = tempfile::tempdir().unwrap();
        write_all(&d, dir.path()).unwrap();
        let files = names(dir.path());
        assert!(
            files.contains(&"iso230_2_deviation_x.svg".to_owned()),
            "{files:?}"
        );
        assert!(files.contains(&"iso230_2_deviation_x.png".to_owned()));
        let svg = std::fs::read_to_string(dir.path().join("iso230_2_deviation_x.svg")).unwrap();
        assert!(svg.contains("deviation = measured − target (µm)"));
        let off = crate::plot::svg_check::texts_off_canvas(&svg);
        assert!(off.is_empty(), "{off:#?}");
    }

    /// No temperature plot without a logged, varying temperature (the
    /// replay's temperature is then the model's assumption, which varies
    /// on the default model), no time plot on synthetic times.
    #[test]
    fn no_plot_of_a_quantity_the_log_lacks() {
        let varying = |i: usize| format!("{:.3}", 20.0 + 0.01 * i as f64);
        let constant = |_: usize| "21.5".to_owned();
        let empty = |_: usize| String::new();
        let half = |i: usize| {
            if i % 2 == 0 {
                String::new()
            } else {
                format!("{:.3}", 20.0 + 0.01 * i as f64)
            }
        };
        type Case<'a> = (&'a str, Option<&'a dyn Fn(usize) -> String>, bool, bool);
        let cases: [Case; 6] = [
            ("no temp_c column", None, false, false),
            ("empty temp_c cells", Some(&empty), false, false),
            ("constant temperature", Some(&constant), false, false),
            ("varying temperature", Some(&varying), false, true),
            ("half the cells logged", Some(&half), false, true),
            ("synthetic times", None, true, false),
        ];
        for (what, temp, synthetic, want_temp) in cases {
            let d = diagnosed(&iso_log(1.0, -1.0, temp, synthetic));
            let dir = tempfile::tempdir().unwrap();
            write_all(&d, dir.path()).unwrap();
            let files = names(dir.path());
            let has = |n: &str| files.iter().any(|f| f == n);
            assert_eq!(
                has("residual_x_vs_temperature.svg"),
                want_temp,
                "{what}: {files:?}"
            );
            assert_eq!(
                has("residual_x_vs_time.svg"),
                !synthetic,
                "{what}: {files:?}"
            );
            assert_eq!(
                has("periodogram_x_vs_time.svg"),
                !synthetic,
                "{what}: {files:?}"
            );
            assert!(has("residual_x_vs_x.svg"), "{what}: {files:?}");
            if want_temp {
                // Only logged temperatures are drawn.
                let n = d.series.temp_c.iter().filter(|t| t.is_finite()).count();
                assert_eq!(n, if what.starts_with("half") { 25 } else { 50 }, "{what}");
            }
        }
    }
}
