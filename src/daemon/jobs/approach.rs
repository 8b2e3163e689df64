//! The direction each axis last moved in, from the commands a job sends,
//! and the log's `approach` cell it gives a point.
//!
//! Why: a characterization reaches the first point of a pass, and the
//! point after a reference detour, by an approach move from the pass's side
//! (`scan_approach`) that is not a logged point. Replayed from the logged
//! points alone, such a point seems reached the other way (the y scan's
//! first forward point, reached from above after the x scan held y at the
//! top), on the other side of the play: `micropos diagnose` then saw a
//! 1.7 µm residual there that the stage never had. The `approach` column
//! says how each point was really reached, and the replay inserts the
//! approach move it implies (`diagnose::data`). A turning point read again
//! without a move keeps the direction it was reached by, not its new
//! pass's.

use crate::analysis::diagnose::APPROACH_COLUMN;
use crate::charact::log::Columns;

/// Smallest command change that counts as a move, µm (commands are sent as
/// computed, so any change is a move; this only absorbs float noise).
const MIN_MOVE_UM: f64 = 1e-6;

/// Tracks the last commanded position and the direction of the last move
/// of each axis (`[x, y]`).
#[derive(Debug, Clone, Default)]
pub(crate) struct ApproachTracker {
    cmd_um: [Option<f64>; 2],
    dir: [Option<f64>; 2],
}

impl ApproachTracker {
    /// Records a move commanded to (`x_um`, `y_um`). The first command
    /// sets the position without a direction (where the axis came from is
    /// not known).
    pub(crate) fn moved_to(&mut self, x_um: f64, y_um: f64) {
        for (a, to) in [x_um, y_um].into_iter().enumerate() {
            if let Some(from) = self.cmd_um[a] {
                if (to - from).abs() > MIN_MOVE_UM {
                    self.dir[a] = Some((to - from).signum());
                }
            }
            self.cmd_um[a] = Some(to);
        }
    }

    /// Direction axis `a` (0: x, 1: y) last moved in: `+1` towards larger
    /// positions, `−1` towards smaller; `None` before any known move.
    pub(crate) fn sign(&self, a: usize) -> Option<f64> {
        self.dir.get(a).copied().flatten()
    }

    /// The `approach` cell of a point of `segment`: the direction its
    /// scanned axis last moved in (`fwd`, `bwd`), empty for a segment that
    /// scans no axis or before any known move.
    pub(crate) fn cell(&self, segment: &str) -> String {
        let axis = match super::scan_line(segment) {
            Some('x') => 0,
            Some(_) => 1,
            None => return String::new(),
        };
        match self.sign(axis) {
            Some(s) if s > 0.0 => "fwd".to_owned(),
            Some(_) => "bwd".to_owned(),
            None => String::new(),
        }
    }
}

/// The step characterization's columns: the jobs' shared ones plus
/// `approach` (see the module doc).
pub fn step_columns() -> Columns {
    let mut c = super::columns();
    c.extra.push(APPROACH_COLUMN.to_owned());
    c
}

/// Whether a log with `columns` carries the `approach` column (a log
/// begun before it existed is resumed without).
pub(crate) fn has_approach(columns: &Columns) -> bool {
    columns.extra.iter().any(|c| c == APPROACH_COLUMN)
}

#[cfg(test)]
mod tests {
    use super::ApproachTracker;

    #[test]
    fn a_turning_point_keeps_the_direction_it_was_reached_by() {
        let mut t = ApproachTracker::default();
        assert_eq!(t.cell("scan_y_fwd"), "");
        // Approach from below, then the forward pass up, then back down.
        t.moved_to(400.0, 400.0);
        t.moved_to(500.0, 500.0);
        assert_eq!(t.cell("scan_y_fwd"), "fwd");
        t.moved_to(500.0, 550.0);
        t.moved_to(500.0, 500.0);
        assert_eq!(t.cell("scan_y_bwd"), "bwd");
        // The next cycle's first forward point, read again without a move.
        t.moved_to(500.0, 500.0);
        assert_eq!(t.cell("scan_y_fwd"), "bwd");
        // x was last moved forward; a drift reference row scans nothing.
        assert_eq!(t.cell("scan_x_bwd"), "fwd");
        assert_eq!(t.cell("drift_ref"), "");
        assert_eq!(t.sign(2), None);
    }
}
