//! The bases the periodic terms share: the direction weights of per-direction
//! parameter sets and the harmonics of a position.

use crate::model::state::Direction;

/// Weights of the forward and backward parameter sets for a direction: the
/// direction's own set, or the mean of both when the direction is unknown.
pub(crate) fn direction_weights(dir: Direction) -> (f64, f64) {
    match dir {
        Direction::Forward => (1.0, 0.0),
        Direction::Backward => (0.0, 1.0),
        Direction::Unknown => (0.5, 0.5),
    }
}

/// `2π·k·p/period` for k = 1..=n as `(sin, cos)` pairs, with `p` reduced
/// modulo the period first so huge positions stay exact and finite.
pub(crate) fn harmonics(p_um: f64, period_um: f64, n: usize) -> Vec<(f64, f64)> {
    let frac = p_um.rem_euclid(period_um) / period_um;
    (1..=n)
        .map(|k| {
            let phi = std::f64::consts::TAU * ((k as f64 * frac).fract());
            phi.sin_cos()
        })
        .collect()
}
