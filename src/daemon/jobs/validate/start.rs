//! Starting a validation: the tables its modes need, its origin, and the
//! checks that refuse it before anything moves (every pose inside the
//! travel, and every pose of a compensated mode inside its table's area),
//! each with the range of origins that fits.

use super::*;
use crate::daemon::protocol::{JobObject, JobReply, PairUm, ValidationStatusReply};

pub(super) async fn resolve(
    rig: &Rig,
    wanted: Option<&str>,
    kind: CompKind,
    mode: &str,
) -> Result<Active, ProtoError> {
    let name = match wanted {
        Some(n) => n.to_owned(),
        None => rig.comp.latest_of_kind(kind).ok_or_else(|| {
            ProtoError::new(
                ErrorCode::NoActiveTable,
                format!(
                    "mode {mode} needs a {} table: tables build LOG (or tables load NAME), or name it in the request",
                    match kind {
                        CompKind::Lookup => "lookup (paper)",
                        CompKind::Model => "model",
                        CompKind::Grid => "grid",
                    }
                ),
            )
        })?,
    };
    if rig.comp.loaded(&name).is_err() {
        rig.comp.load(&rig.cfg.daemon.data_dir, &name).await?;
    }
    rig.comp.loaded(&name)
}

impl Jobs {
    /// `validate status`: progress and the results of the current or last
    /// validation.
    pub fn validation_status(&self) -> ValidationStatusReply {
        let job = lock(&self.progress)
            .as_ref()
            .filter(|p| p.kind == JobKind::Validate)
            .map(|p| JobObject::from(p.to_reply()));
        let validation = lock(&self.validation).clone().unwrap_or(Value::Null);
        ValidationStatusReply { job, validation }
    }

    /// `validate start`. Every refusal comes before anything moves: the
    /// tables the modes need, every pose inside the travel, and every pose
    /// of a compensated mode inside its table's area.
    pub async fn start_validation(
        &self,
        rig: &Arc<Rig>,
        p: ValidateParams,
    ) -> Result<JobReply, ProtoError> {
        self.check_can_start(rig, "validation")?;
        let comps = resolve_comps(rig, &p).await?;
        let frame = comps
            .table
            .as_ref()
            .and_then(|a| a.frame)
            .or_else(|| comps.model.as_ref().and_then(|a| a.frame));
        let d = &rig.cfg.characterize;
        let travel = travel(rig)?;
        let mut tests = Vec::new();
        for t in &p.tests {
            if t == "square" {
                tests.push((
                    SEGMENT_SQUARE,
                    square(p.square_step_um.unwrap_or(DEFAULT_SQUARE_STEP_UM))?,
                ));
            } else {
                tests.push((SEGMENT_RANDOM, random()));
            }
        }
        let span = pose_span(&tests);
        let origin = validation_origin(d, &p, span, travel);
        let plan = Plan {
            tests,
            modes: p.modes.clone(),
            cycles: p.cycles.unwrap_or(DEFAULT_CYCLES),
            origin,
            frames: p.frames_per_point.unwrap_or(d.frames_per_point),
            settle_s: p.settle_s.unwrap_or(d.settle_s),
            comps,
            frame,
        };
        check_poses_in_travel(&plan, span, travel)?;
        let warnings = check_table_areas(rig, &plan, span, travel)?;
        let name = p
            .log
            .clone()
            .unwrap_or_else(|| format!("validate-{}.csv", super::super::unix_seconds()));
        let path = rig.cfg.daemon.data_dir.join(&name);
        if path.exists() {
            return Err(ProtoError::new(
                ErrorCode::LogError,
                format!("log {name} exists already; choose another name"),
            ));
        }
        rig.begin_job()?;
        let launch = Launch {
            kind: JobKind::Validate,
            what: format!("validation {name}"),
            logs: vec![name.clone()],
            done: 0,
            total: plan.total(),
        };
        let (rig2, progress) = (rig.clone(), self.progress.clone());
        let mut out = self.spawn(rig, launch, |cancel| async move {
            let (state, results) = run(&rig2, &plan, &name, &progress, cancel).await?;
            Ok(Ended {
                validation: results.map(|r| json!({"results": r, "logs": [name]})),
                ..Ended::state(state)
            })
        });
        out.origin = Some(PairUm::of([origin.x_um, origin.y_um]));
        out.warnings = (!warnings.is_empty()).then_some(warnings);
        Ok(out)
    }
}

/// The tables the requested modes use: named in the request, else the
/// latest loaded of their kind (`closed_loop` takes the lookup table, else
/// the model table). Refused when one is missing, or when `closed_loop`'s
/// table does not record the vision frame it corrects in.
pub(super) async fn resolve_comps(rig: &Rig, p: &ValidateParams) -> Result<Comps, ProtoError> {
    let needs_table = p.modes.iter().any(|m| matches!(m, ValidateMode::Table));
    let needs_model = p.modes.contains(&ValidateMode::Model);
    let needs_any = p.modes.contains(&ValidateMode::ClosedLoop);
    let mut comps = Comps {
        table: None,
        model: None,
    };
    if needs_table || p.table.is_some() {
        comps.table = Some(resolve(rig, p.table.as_deref(), CompKind::Lookup, "table").await?);
    }
    if needs_model || p.model_table.is_some() {
        comps.model = Some(resolve(rig, p.model_table.as_deref(), CompKind::Model, "model").await?);
    }
    if needs_any && comps.table.is_none() && comps.model.is_none() {
        comps.table = resolve(rig, None, CompKind::Lookup, "closed_loop")
            .await
            .ok();
        if comps.table.is_none() {
            comps.model = Some(resolve(rig, None, CompKind::Model, "closed_loop").await?);
        }
    }
    if needs_any
        && comps
            .for_mode(ValidateMode::ClosedLoop)
            .and_then(|a| a.frame)
            .is_none()
    {
        return Err(ProtoError::new(
            ErrorCode::NoActiveTable,
            "closed_loop needs a table that records the vision frame (built by tables build)",
        ));
    }
    Ok(comps)
}

/// The allowed travel `[(x_lo, x_hi), (y_lo, y_hi)]`, µm, from the
/// controllers' limits; refused while they are not connected.
pub(super) fn travel(rig: &Rig) -> Result<[(f64, f64); 2], ProtoError> {
    match rig.status().limits {
        Some(l) => Ok([(l.x_um[0], l.x_um[1]), (l.y_um[0], l.y_um[1])]),
        None => Err(ProtoError::new(
            ErrorCode::NotConnected,
            "the controllers are not connected",
        )),
    }
}

/// Where the paper's (0, 0) goes on the stage, µm: the request's, else the
/// characterization start, so that the validation covers the
/// characterized area as in the paper. Along an axis where the poses
/// (spanning `span`) would leave the travel from there (a scan of a small
/// area, centred in the travel), the paper's own placement instead: from
/// the travel's start (its scans and validation ran from 0),
/// `ORIGIN_CLEARANCE_UM` in where the travel allows.
pub(super) fn validation_origin(
    d: &crate::daemon::config::CharacterizeDefaults,
    p: &ValidateParams,
    span: Option<[[f64; 2]; 2]>,
    travel: [(f64, f64); 2],
) -> XyUm {
    let [xl, yl] = travel;
    let fits = span.map(|s| [0, 1].map(|a| origin_range(s[a], travel[a])));
    let preferred = [
        d.x_start_um.unwrap_or((xl.0 + xl.1 - d.x_range_um) / 2.0),
        d.y_start_um.unwrap_or((yl.0 + yl.1 - d.y_range_um) / 2.0),
    ];
    let named = [p.origin_x_um, p.origin_y_um];
    let o = [0, 1].map(|a| {
        let plain = fits.and_then(|f| f[a]);
        let c = ORIGIN_CLEARANCE_UM;
        let cleared = span.and_then(|s| origin_range(s[a], (travel[a].0 + c, travel[a].1 - c)));
        match named[a] {
            Some(v) => v,
            None if plain.is_some_and(|(lo, hi)| (lo..=hi).contains(&preferred[a])) => preferred[a],
            None => cleared.or(plain).map_or(preferred[a], |(lo, _)| lo),
        }
    });
    XyUm {
        x_um: o[0],
        y_um: o[1],
    }
}

/// Refuses a plan with a pose outside the travel (`out_of_travel`, with
/// the range of origins that fits).
pub(super) fn check_poses_in_travel(
    plan: &Plan,
    span: Option<[[f64; 2]; 2]>,
    travel: [(f64, f64); 2],
) -> Result<(), ProtoError> {
    let ([xl, yl], origin) = (travel, plan.origin);
    for (_, poses) in &plan.tests {
        for pose in poses {
            let t = plan.target(pose);
            if !(xl.0..=xl.1).contains(&t.x_um) || !(yl.0..=yl.1).contains(&t.y_um) {
                return Err(ProtoError::new(
                    ErrorCode::OutOfTravel,
                    format!(
                        "validation pose {} would be at ({:.1}, {:.1}) µm with the origin ({:.1}, {:.1}) µm, outside the travel x {:.1} … {:.1} µm, y {:.1} … {:.1} µm; {}",
                        pose.label,
                        t.x_um,
                        t.y_um,
                        origin.x_um,
                        origin.y_um,
                        xl.0,
                        xl.1,
                        yl.0,
                        yl.1,
                        origin_advice(
                            span,
                            travel,
                            "the travel",
                            "validate fewer poses (validate start --test square, or --test random)"
                        )
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Compensated modes outside their table's characterized area: refused
/// (or warned: the warnings returned) before anything moves. The targets
/// are in the measuring frame; a table's frame differs from it by a tie's
/// drift (≈ 0.5 µm), which `outside_margin_um` absorbs.
pub(super) fn check_table_areas(
    rig: &Rig,
    plan: &Plan,
    span: Option<[[f64; 2]; 2]>,
    travel: [(f64, f64); 2],
) -> Result<Vec<String>, ProtoError> {
    let cfg = rig.live.compensation();
    let mut warnings: Vec<String> = Vec::new();
    for mode in &plan.modes {
        if !matches!(mode, ValidateMode::Table | ValidateMode::Model) {
            continue;
        }
        let Some(a) = plan.comps.for_mode(*mode) else {
            continue;
        };
        for (_, poses) in &plan.tests {
            if let Some(w) = poses.iter().find_map(|pose| {
                let what = format!("mode {} pose {}", mode.as_str(), pose.label);
                check_area(&*a.comp, &a.name, plan.target(pose), &cfg, &what).transpose()
            }) {
                let w = w.map_err(|e| outside_table(e, &a, &cfg, plan.origin, span, travel))?;
                if let Some(t) = w.warning {
                    warnings.push(t);
                }
            }
        }
    }
    Ok(warnings)
}

/// A table-area refusal with the origin and the range of origins that
/// keeps the poses inside both the table's area and the travel.
pub(super) fn outside_table(
    e: ProtoError,
    a: &Active,
    cfg: &crate::daemon::config::CompensationSection,
    origin: XyUm,
    span: Option<[[f64; 2]; 2]>,
    travel: [(f64, f64); 2],
) -> ProtoError {
    let [xl, yl] = travel;
    let inside = a.comp.characterized_area().map(|r| {
        let m = cfg.outside_margin_um;
        let within = |r: [f64; 2], t: (f64, f64)| ((r[0] - m).max(t.0), (r[1] + m).min(t.1));
        [within(r.x_um, xl), within(r.y_um, yl)]
    });
    let advice = inside.map_or_else(String::new, |b| {
        format!(
            "; {}",
            origin_advice(
                span,
                b,
                "that area and the travel",
                "characterize an area that covers them, or validate without table \
                 modes (validate start --modes raw,closed_loop)"
            )
        )
    });
    ProtoError::new(
        e.code,
        format!(
            "{}; the validation origin is ({:.1}, {:.1}) µm{advice}",
            e.message, origin.x_um, origin.y_um
        ),
    )
}

/// The span of the poses' paper coordinates, `[[x_lo, x_hi], [y_lo,
/// y_hi]]` µm; `None` without poses.
pub(super) fn pose_span(tests: &[(&'static str, Vec<Pose>)]) -> Option<[[f64; 2]; 2]> {
    let mut it = tests.iter().flat_map(|(_, p)| p).map(|p| p.paper_um);
    let first = it.next()?;
    Some(it.fold(
        [[first.x_um, first.x_um], [first.y_um, first.y_um]],
        |[x, y], p| {
            [
                [x[0].min(p.x_um), x[1].max(p.x_um)],
                [y[0].min(p.y_um), y[1].max(p.y_um)],
            ]
        },
    ))
}

/// The origins along one axis that keep poses spanning `span` (paper
/// coordinates, µm) within `allowed` (stage µm): `[allowed.0 − span[0],
/// allowed.1 − span[1]]`; `None` when the span is longer than `allowed`
/// (or anything is not finite).
pub(super) fn origin_range(span: [f64; 2], allowed: (f64, f64)) -> Option<(f64, f64)> {
    let (lo, hi) = (allowed.0 - span[0], allowed.1 - span[1]);
    (lo.is_finite() && hi.is_finite() && lo <= hi).then_some((lo, hi))
}

/// What origin would do, for an error: the range of origins that keeps
/// the poses (spanning `span`) inside `allowed` (per axis, stage µm;
/// `what` names it), with the CLI flags and request fields that set it,
/// or why none does and what would (`remedy`). Why: the user chose (or
/// took the default of) an origin that does not fit, and only the daemon
/// knows the travel and the poses' extent to say which would.
pub(super) fn origin_advice(
    span: Option<[[f64; 2]; 2]>,
    allowed: [(f64, f64); 2],
    what: &str,
    remedy: &str,
) -> String {
    let Some(s) = span else {
        return "choose another origin (validate start --origin-x-um X --origin-y-um Y)".into();
    };
    let lie = format!(
        "the poses lie x {:.1} … {:.1} µm and y {:.1} … {:.1} µm from the origin",
        s[0][0], s[0][1], s[1][0], s[1][1]
    );
    match [0, 1].map(|a| origin_range(s[a], allowed[a])) {
        [Some(x), Some(y)] => format!(
            "{lie}, so an origin x {:.1} … {:.1} µm, y {:.1} … {:.1} µm keeps every one inside {what}: \
             validate start --origin-x-um X --origin-y-um Y (request fields origin_x_um, origin_y_um)",
            x.0, x.1, y.0, y.1
        ),
        r => {
            let short: Vec<String> = [("x", 0), ("y", 1)]
                .iter()
                .filter(|(_, a)| r[*a].is_none())
                .map(|&(n, a)| {
                    format!(
                        "{n} ({:.1} µm of poses, {:.1} µm available)",
                        s[a][1] - s[a][0],
                        (allowed[a].1 - allowed[a].0).max(0.0)
                    )
                })
                .collect();
            format!(
                "{lie}: no origin keeps every one inside {what}, too short in {}; {remedy}",
                short.join(" and ")
            )
        }
    }
}
