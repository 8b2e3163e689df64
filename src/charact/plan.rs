//! The characterization scan plan, pure: the ordered list of points, and
//! its round trip through the measurement log's metadata so a resumed job
//! rebuilds exactly the plan it started with (point `k` of the log is point
//! `k` of the plan: resume continues at index = records already logged).

use crate::charact::log::Metadata;
use crate::charact::scan::{grid_segment, SEGMENT_MOVES};
use crate::model::Direction;

/// One point of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// `scan_x_fwd`, `scan_x_bwd`, `scan_y_fwd`, `scan_y_bwd`.
    pub segment: &'static str,
    /// 1-based cycle.
    pub cycle: u32,
    /// X target, µm (controller coordinates).
    pub x_um: f64,
    /// Y target, µm.
    pub y_um: f64,
}

pub use crate::charact::scan::SEGMENT_GRID;

/// Per-axis 1-DoF scans, the other axis held at the centre of its range;
/// or, with `grid`, every node of a lattice over the area.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanPlan {
    /// A grid plan: nodes `x_start + i·step`, `y_start + j·step` over both
    /// ranges, in rows of increasing x, rows in increasing y, per cycle
    /// (segment [`SEGMENT_GRID`]; `scan_x`/`scan_y` play no part).
    pub grid: bool,
    /// A grid measured both ways: per cycle every node from below (segment
    /// `grid_fwd`, as above), then every node from above
    /// (`grid_bwd`: rows of decreasing x, in decreasing y).
    pub grid_both: bool,
    /// A grid in serpentine order (needs `grid_both`): the rows of the pass
    /// from below alternate in x (increasing, then decreasing), so no row
    /// starts with a return move; the pass from above visits the same
    /// nodes in reverse. Every node is still reached once each way on each
    /// axis; each record's segment names its two directions
    /// (`crate::charact::scan::grid_direction`).
    pub grid_serpentine: bool,
    /// Scan X.
    pub scan_x: bool,
    /// Scan Y.
    pub scan_y: bool,
    /// Step, µm.
    pub step_um: f64,
    /// First X point, µm.
    pub x_start_um: f64,
    /// X range, µm.
    pub x_range_um: f64,
    /// First Y point, µm.
    pub y_start_um: f64,
    /// Y range, µm.
    pub y_range_um: f64,
    /// Forward + backward cycles.
    pub cycles: u32,
    /// Frames averaged per point.
    pub frames_per_point: u32,
    /// Settle time, s.
    pub settle_s: f64,
    /// Moves of varied length per cycle after the scans (segment
    /// [`SEGMENT_MOVES`]): points spread over the scanned area, each reached
    /// by one direct move from the one before, as an application moves. A
    /// model table fitted to such a log identifies a lost motion that grows
    /// with the move length (`comp::model_comp`); 0 = none (the paper's
    /// plan).
    pub moves_per_cycle: u32,
}

/// Where the `k`-th move of a plan goes, as fractions of the ranges:
/// uniform pseudo-random (SplitMix64 of `k`), so a resumed job rebuilds the
/// same points and the moves between consecutive points have every length
/// from a few µm to the whole range, as an application's.
fn moves_fraction(k: u32) -> (f64, f64) {
    fn splitmix(mut z: u64) -> u64 {
        z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    // The top 53 bits as a fraction in [0, 1).
    let unit = |z: u64| (z >> 11) as f64 / (1u64 << 53) as f64;
    let k = u64::from(k);
    (unit(splitmix(2 * k)), unit(splitmix(2 * k + 1)))
}

/// A two-way metadata choice: `false` for `words[0]` (or no entry),
/// `true` for `words[1]`, an error naming both for anything else.
fn either(md: &Metadata, key: &str, words: [&str; 2]) -> Result<bool, PlanError> {
    match md.get(key) {
        None => Ok(false),
        Some(v) if v == words[0] => Ok(false),
        Some(v) if v == words[1] => Ok(true),
        Some(other) => Err(PlanError {
            key: key.to_owned(),
            problem: format!("{other:?} is neither {:?} nor {:?}", words[0], words[1]),
        }),
    }
}

/// A metadata entry was missing or unreadable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("log metadata {key}: {problem}")]
pub struct PlanError {
    /// The metadata key.
    pub key: String,
    /// What is wrong.
    pub problem: String,
}

const KEYS: [&str; 10] = [
    "scan_x",
    "scan_y",
    "step_um",
    "x_start_um",
    "x_range_um",
    "y_start_um",
    "y_range_um",
    "cycles",
    "frames_per_point",
    "settle_s",
];

impl ScanPlan {
    fn steps(range_um: f64, step_um: f64) -> u32 {
        // Tolerate rounding: 9500 / 5 is 1900 steps, not 1899.
        ((range_um / step_um) + 1e-9).floor() as u32
    }

    /// Every point, in order.
    pub fn points(&self) -> Vec<Point> {
        let mut v = Vec::new();
        if self.grid {
            let xs = self.grid_nodes(self.x_start_um, self.x_range_um);
            let ys = self.grid_nodes(self.y_start_um, self.y_range_um);
            for cycle in 1..=self.cycles {
                self.push_grid_cycle(&mut v, cycle, &xs, &ys);
            }
            self.push_moves(&mut v);
            return v;
        }
        let x_hold = self.x_start_um + self.x_range_um / 2.0;
        let y_hold = self.y_start_um + self.y_range_um / 2.0;
        let mut scan = |on: bool,
                        fwd: &'static str,
                        bwd: &'static str,
                        start: f64,
                        range: f64,
                        x_axis: bool| {
            if !on {
                return;
            }
            let n = Self::steps(range, self.step_um);
            for cycle in 1..=self.cycles {
                for (seg, idx) in [
                    (fwd, (0..=n).collect::<Vec<_>>()),
                    (bwd, (0..=n).rev().collect()),
                ] {
                    for i in idx {
                        let p = start + f64::from(i) * self.step_um;
                        let (x_um, y_um) = if x_axis { (p, y_hold) } else { (x_hold, p) };
                        v.push(Point {
                            segment: seg,
                            cycle,
                            x_um,
                            y_um,
                        });
                    }
                }
            }
        };
        scan(
            self.scan_x,
            "scan_x_fwd",
            "scan_x_bwd",
            self.x_start_um,
            self.x_range_um,
            true,
        );
        scan(
            self.scan_y,
            "scan_y_fwd",
            "scan_y_bwd",
            self.y_start_um,
            self.y_range_um,
            false,
        );
        self.push_moves(&mut v);
        v
    }

    /// One cycle of a grid: the pass from below (raster: every row in
    /// increasing x; serpentine: alternating), then with `grid_both` the
    /// same nodes in reverse order, each reached the other way on both
    /// axes.
    fn push_grid_cycle(&self, v: &mut Vec<Point>, cycle: u32, xs: &[f64], ys: &[f64]) {
        use Direction::{Backward, Forward};
        let mut up: Vec<(f64, f64, [Direction; 2])> = Vec::new();
        for (i, &y_um) in ys.iter().enumerate() {
            let back = self.grid_serpentine && i % 2 == 1;
            let row: Vec<f64> = if back {
                xs.iter().rev().copied().collect()
            } else {
                xs.to_vec()
            };
            let dx = if back { Backward } else { Forward };
            up.extend(row.into_iter().map(|x_um| (x_um, y_um, [dx, Forward])));
        }
        let flip = |d: Direction| if d == Forward { Backward } else { Forward };
        let down: Vec<(f64, f64, [Direction; 2])> = if self.grid_both {
            up.iter()
                .rev()
                .map(|&(x, y, d)| (x, y, [flip(d[0]), flip(d[1])]))
                .collect()
        } else {
            Vec::new()
        };
        for (x_um, y_um, dirs) in up.into_iter().chain(down) {
            v.push(Point {
                segment: if self.grid_both {
                    grid_segment(dirs)
                } else {
                    SEGMENT_GRID
                },
                cycle,
                x_um,
                y_um,
            });
        }
    }

    /// A grid's node positions along one axis: every `step_um` from
    /// `start`, and the range's end when the pitch does not divide the
    /// range (so the map covers the whole characterized area; its last
    /// cell is narrower).
    fn grid_nodes(&self, start_um: f64, range_um: f64) -> Vec<f64> {
        let n = Self::steps(range_um, self.step_um);
        let mut v: Vec<f64> = (0..=n)
            .map(|i| start_um + f64::from(i) * self.step_um)
            .collect();
        if range_um - f64::from(n) * self.step_um > 1e-6 {
            v.push(start_um + range_um);
        }
        v
    }

    /// The plan's moves of varied length (`moves_per_cycle`), after its
    /// scans or grid.
    fn push_moves(&self, v: &mut Vec<Point>) {
        let mut k = 0;
        for cycle in 1..=self.cycles {
            for _ in 0..self.moves_per_cycle {
                let (fx, fy) = moves_fraction(k);
                k += 1;
                v.push(Point {
                    segment: SEGMENT_MOVES,
                    cycle,
                    x_um: self.x_start_um + fx * self.x_range_um,
                    y_um: self.y_start_um + fy * self.y_range_um,
                });
            }
        }
    }

    /// How many points the plan has, at most (a float, so that an absurd
    /// plan is refused before its point list is built).
    pub fn points_upper_bound(&self) -> f64 {
        let n = |r: f64| (r / self.step_um).min(1e7) + 2.0;
        let per_cycle = if self.grid {
            n(self.x_range_um) * n(self.y_range_um) * if self.grid_both { 2.0 } else { 1.0 }
        } else {
            2.0 * (n(self.x_range_um) + n(self.y_range_um))
        };
        (per_cycle + f64::from(self.moves_per_cycle)) * f64::from(self.cycles)
    }

    /// Writes the plan into log metadata.
    pub fn to_metadata(&self, md: &mut Metadata) {
        let vals = [
            self.scan_x.to_string(),
            self.scan_y.to_string(),
            self.step_um.to_string(),
            self.x_start_um.to_string(),
            self.x_range_um.to_string(),
            self.y_start_um.to_string(),
            self.y_range_um.to_string(),
            self.cycles.to_string(),
            self.frames_per_point.to_string(),
            self.settle_s.to_string(),
        ];
        md.insert("job", "characterize");
        for (k, v) in KEYS.iter().zip(vals) {
            md.insert(*k, v);
        }
        if self.moves_per_cycle > 0 {
            md.insert("moves_per_cycle", self.moves_per_cycle.to_string());
        }
        if self.grid {
            md.insert("plan", "grid");
        }
        if self.grid_both {
            md.insert("grid_approach", "both");
        }
        if self.grid_serpentine {
            md.insert("grid_order", "serpentine");
        }
    }

    /// Reads a plan back from log metadata.
    pub fn from_metadata(md: &Metadata) -> Result<ScanPlan, PlanError> {
        fn get<T: std::str::FromStr>(md: &Metadata, key: &str) -> Result<T, PlanError> {
            let v = md.get(key).ok_or_else(|| PlanError {
                key: key.to_owned(),
                problem: "missing (not a log written by a microposd characterization?)".to_owned(),
            })?;
            v.parse().map_err(|_| PlanError {
                key: key.to_owned(),
                problem: format!("{v:?} is not a valid value"),
            })
        }
        let grid = either(md, "plan", ["lines", "grid"])?;
        let grid_both = either(md, "grid_approach", ["below", "both"])?;
        let grid_serpentine = either(md, "grid_order", ["raster", "serpentine"])?;
        let p = ScanPlan {
            grid,
            grid_both: grid && grid_both,
            grid_serpentine: grid && grid_both && grid_serpentine,
            scan_x: get(md, "scan_x")?,
            scan_y: get(md, "scan_y")?,
            step_um: get(md, "step_um")?,
            x_start_um: get(md, "x_start_um")?,
            x_range_um: get(md, "x_range_um")?,
            y_start_um: get(md, "y_start_um")?,
            y_range_um: get(md, "y_range_um")?,
            cycles: get(md, "cycles")?,
            frames_per_point: get(md, "frames_per_point")?,
            settle_s: get(md, "settle_s")?,
            // Absent in logs of plans without moves.
            moves_per_cycle: match md.get("moves_per_cycle") {
                None => 0,
                Some(_) => get(md, "moves_per_cycle")?,
            },
        };
        let finite = [
            p.step_um,
            p.x_start_um,
            p.x_range_um,
            p.y_start_um,
            p.y_range_um,
            p.settle_s,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite
            || p.step_um <= 0.0
            || p.x_range_um <= 0.0
            || p.y_range_um <= 0.0
            || p.cycles == 0
            || p.frames_per_point == 0
            || p.settle_s < 0.0
        {
            return Err(PlanError {
                key: "step_um".to_owned(),
                problem: "the plan in this log is not usable (non-positive step, range or count)"
                    .to_owned(),
            });
        }
        // Refuse plans so large the point list itself would be a problem.
        if p.points_upper_bound() > 1e7 {
            return Err(PlanError {
                key: "step_um".to_owned(),
                problem: "the plan has more than 10 million points".to_owned(),
            });
        }
        Ok(p)
    }
}

/// Reference re-measurements during a characterization (`drift_every_s`):
/// every `every_s` of rig time the job measures `reference_um` and logs it
/// with segment [`crate::analysis::drift::DRIFT_REF_SEGMENT`], so that
/// `tables build` can subtract the drift. Stored in the log metadata so a
/// resumed job keeps doing it; absent keys = off (a log without them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftPlan {
    /// Interval between re-measurements, s of rig time (> 0).
    pub every_s: f64,
    /// Reference point `[x, y]`, µm (controller coordinates); always
    /// approached forward on both axes from [`crate::charact::scan::PARK_APPROACH_UM`]
    /// below, so backlash is the same at every re-measurement.
    pub reference_um: [f64; 2],
}

impl DriftPlan {
    /// Writes the drift plan into log metadata.
    pub fn to_metadata(&self, md: &mut Metadata) {
        md.insert("drift_every_s", self.every_s.to_string());
        md.insert("drift_reference_x_um", self.reference_um[0].to_string());
        md.insert("drift_reference_y_um", self.reference_um[1].to_string());
    }

    /// Reads it back; `Ok(None)` when the log has no `drift_every_s` (or 0).
    pub fn from_metadata(md: &Metadata) -> Result<Option<DriftPlan>, PlanError> {
        let get = |key: &str| -> Result<Option<f64>, PlanError> {
            match md.get(key) {
                None => Ok(None),
                Some(v) => match v.parse::<f64>() {
                    Ok(x) if x.is_finite() => Ok(Some(x)),
                    _ => Err(PlanError {
                        key: key.to_owned(),
                        problem: format!("{v:?} is not a finite number"),
                    }),
                },
            }
        };
        let every_s = match get("drift_every_s")? {
            None => return Ok(None),
            Some(0.0) => return Ok(None),
            Some(v) if v < 0.0 => {
                return Err(PlanError {
                    key: "drift_every_s".to_owned(),
                    problem: format!("{v} is negative"),
                })
            }
            Some(v) => v,
        };
        let coord = |key: &str| {
            get(key)?.ok_or_else(|| PlanError {
                key: key.to_owned(),
                problem: "missing while drift_every_s is set".to_owned(),
            })
        };
        Ok(Some(DriftPlan {
            every_s,
            reference_um: [
                coord("drift_reference_x_um")?,
                coord("drift_reference_y_um")?,
            ],
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> ScanPlan {
        ScanPlan {
            grid: false,
            grid_both: false,
            grid_serpentine: false,
            scan_x: true,
            scan_y: true,
            step_um: 5.0,
            x_start_um: 2750.0,
            x_range_um: 9500.0,
            y_start_um: 5400.0,
            y_range_um: 4200.0,
            cycles: 3,
            frames_per_point: 4,
            settle_s: 0.5,
            moves_per_cycle: 0,
        }
    }

    /// A grid plan: every node of the lattice once per cycle, rows of
    /// increasing x, rows in increasing y; it round-trips through the
    /// metadata, and a plain plan writes no `plan` key.
    #[test]
    fn a_grid_plan_visits_every_node_in_rows_and_round_trips() {
        let p = ScanPlan {
            grid: true,
            step_um: 500.0,
            x_range_um: 2000.0,
            y_range_um: 1000.0,
            cycles: 2,
            ..plan()
        };
        let pts = p.points();
        assert_eq!(pts.len(), 2 * 5 * 3);
        assert!(pts.iter().all(|q| q.segment == SEGMENT_GRID));
        assert_eq!((pts[0].x_um, pts[0].y_um), (2750.0, 5400.0));
        assert_eq!((pts[4].x_um, pts[4].y_um), (4750.0, 5400.0));
        assert_eq!((pts[5].x_um, pts[5].y_um), (2750.0, 5900.0));
        assert_eq!(
            (pts[14].x_um, pts[14].y_um, pts[14].cycle),
            (4750.0, 6400.0, 1)
        );
        assert_eq!(pts[15].cycle, 2);
        // A pitch that does not divide a range: its end is a node too.
        let q = ScanPlan {
            y_range_um: 1200.0,
            cycles: 1,
            ..p.clone()
        };
        let ys: Vec<f64> = q.points().iter().step_by(5).map(|n| n.y_um).collect();
        assert_eq!(ys, [5400.0, 5900.0, 6400.0, 6600.0]);
        let mut md = Metadata::new();
        p.to_metadata(&mut md);
        assert_eq!(md.get("plan"), Some("grid"));
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), p);
        let mut md = Metadata::new();
        plan().to_metadata(&mut md);
        assert!(md.get("plan").is_none());
        assert!(!ScanPlan::from_metadata(&md).unwrap().grid);
        md.insert("plan", "spiral");
        assert!(ScanPlan::from_metadata(&md).is_err());
    }

    /// A grid measured both ways: per cycle the pass from below, then the
    /// same nodes from above in reverse order; it round-trips.
    #[test]
    fn a_grid_both_ways_visits_every_node_from_each_side() {
        use crate::charact::scan::{SEGMENT_GRID_BWD, SEGMENT_GRID_FWD};
        let p = ScanPlan {
            grid: true,
            grid_both: true,
            step_um: 500.0,
            x_range_um: 2000.0,
            y_range_um: 1000.0,
            cycles: 2,
            ..plan()
        };
        let pts = p.points();
        assert_eq!(pts.len(), 2 * 2 * 15);
        assert!(pts[..15].iter().all(|q| q.segment == SEGMENT_GRID_FWD));
        assert!(pts[15..30].iter().all(|q| q.segment == SEGMENT_GRID_BWD));
        for k in 0..15 {
            let (a, b) = (&pts[k], &pts[29 - k]);
            assert_eq!((a.x_um, a.y_um, a.cycle), (b.x_um, b.y_um, 1));
        }
        assert_eq!(pts[30].segment, SEGMENT_GRID_FWD);
        assert_eq!(pts[30].cycle, 2);
        assert!(p.points_upper_bound() >= pts.len() as f64);
        let mut md = Metadata::new();
        p.to_metadata(&mut md);
        assert_eq!(md.get("grid_approach"), Some("both"));
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), p);
        md.insert("grid_approach", "sideways");
        assert!(ScanPlan::from_metadata(&md).is_err());
    }

    /// A serpentine grid both ways: rows alternate in x, the pass from
    /// above is the pass from below reversed, and every node is reached
    /// once each way on each axis, as its segment says.
    #[test]
    fn a_serpentine_grid_reaches_every_node_each_way_on_each_axis() {
        use crate::charact::scan::grid_direction;
        let p = ScanPlan {
            grid: true,
            grid_both: true,
            grid_serpentine: true,
            step_um: 500.0,
            x_range_um: 2000.0,
            y_range_um: 1000.0,
            cycles: 1,
            ..plan()
        };
        let pts = p.points();
        assert_eq!(pts.len(), 30);
        // Row 1 runs back in x, without a return move.
        assert_eq!((pts[4].x_um, pts[5].x_um), (4750.0, 4750.0));
        assert!(pts[5].y_um > pts[4].y_um && pts[6].x_um < pts[5].x_um);
        let mut seen: std::collections::HashMap<(u64, u64), Vec<[Direction; 2]>> =
            std::collections::HashMap::new();
        let mut last: Option<&Point> = None;
        for q in &pts {
            let d = grid_direction(q.segment).expect("a directed grid segment");
            // Where an axis moves, it moves the way the segment says.
            if let Some(l) = last {
                for (a, (from, to)) in [(l.x_um, q.x_um), (l.y_um, q.y_um)].into_iter().enumerate()
                {
                    if to != from && q.segment == l.segment {
                        assert_eq!((to > from), d[a] == Direction::Forward, "{q:?}");
                    }
                }
            }
            seen.entry((q.x_um.to_bits(), q.y_um.to_bits()))
                .or_default()
                .push(d);
            last = Some(q);
        }
        assert_eq!(seen.len(), 15);
        for ways in seen.values() {
            for a in 0..2 {
                let fwd = ways.iter().filter(|d| d[a] == Direction::Forward).count();
                assert_eq!((fwd, ways.len()), (1, 2), "{ways:?}");
            }
        }
        let mut md = Metadata::new();
        p.to_metadata(&mut md);
        assert_eq!(md.get("grid_order"), Some("serpentine"));
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), p);
    }

    #[test]
    fn moves_follow_the_scans_spread_over_the_area_and_round_trip() {
        let p = ScanPlan {
            moves_per_cycle: 40,
            ..plan()
        };
        let pts = p.points();
        let scans = plan().points().len();
        assert_eq!(pts.len(), scans + 3 * 40);
        let moves = &pts[scans..];
        assert!(moves.iter().all(|m| m.segment == SEGMENT_MOVES));
        assert_eq!(
            (moves[0].cycle, moves[40].cycle, moves[119].cycle),
            (1, 2, 3)
        );
        let mut lengths = Vec::new();
        for w in moves.windows(2) {
            for (a, b, lo, r) in [
                (w[0].x_um, w[1].x_um, p.x_start_um, p.x_range_um),
                (w[0].y_um, w[1].y_um, p.y_start_um, p.y_range_um),
            ] {
                assert!((lo..=lo + r).contains(&b));
                lengths.push((b - a).abs() / r);
            }
        }
        // Moves of every length, short to most of the range.
        let short = lengths.iter().filter(|l| **l < 0.1).count();
        let long = lengths.iter().filter(|l| **l > 0.5).count();
        assert!(short > 5 && long > 50, "{short} short, {long} long");
        let mut md = Metadata::new();
        p.to_metadata(&mut md);
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), p);
        assert_eq!(ScanPlan::from_metadata(&md).unwrap().points(), pts);
        // A plan without moves writes no key (older logs read as 0).
        let mut md = Metadata::new();
        plan().to_metadata(&mut md);
        assert!(md.get("moves_per_cycle").is_none());
    }

    #[test]
    fn default_plan_has_the_expected_points() {
        let pts = plan().points();
        assert_eq!(pts.len(), 1901 * 2 * 3 + 841 * 2 * 3);
        assert_eq!(
            pts[0],
            Point {
                segment: "scan_x_fwd",
                cycle: 1,
                x_um: 2750.0,
                y_um: 7500.0
            }
        );
        assert_eq!(pts[1900].x_um, 12250.0);
        assert_eq!(pts[1901].segment, "scan_x_bwd");
        assert_eq!(pts[1901].x_um, 12250.0);
        let y0 = &pts[1901 * 6];
        assert_eq!(
            (y0.segment, y0.x_um, y0.y_um),
            ("scan_y_fwd", 7500.0, 5400.0)
        );
    }

    #[test]
    fn plan_round_trips_through_metadata() {
        let mut md = Metadata::new();
        let p = plan();
        p.to_metadata(&mut md);
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), p);
        let mut md2 = Metadata::new();
        md2.insert("step_um", "x");
        assert!(ScanPlan::from_metadata(&md2).is_err());
    }

    #[test]
    fn drift_plan_round_trips_and_is_off_by_default() {
        let mut md = Metadata::new();
        plan().to_metadata(&mut md);
        assert_eq!(DriftPlan::from_metadata(&md).unwrap(), None);
        let d = DriftPlan {
            every_s: 600.0,
            reference_um: [2750.0, 5400.5],
        };
        d.to_metadata(&mut md);
        assert_eq!(DriftPlan::from_metadata(&md).unwrap(), Some(d));
        // The scan plan is unaffected by the extra keys.
        assert_eq!(ScanPlan::from_metadata(&md).unwrap(), plan());
        md.insert("drift_reference_y_um", "nan");
        assert!(DriftPlan::from_metadata(&md).is_err());
        md.insert("drift_every_s", "-1");
        assert!(DriftPlan::from_metadata(&md).is_err());
        md.insert("drift_every_s", "0");
        assert_eq!(DriftPlan::from_metadata(&md).unwrap(), None);
    }
}
