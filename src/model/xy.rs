//! A position in the stage frame, µm: the one point type of the model, the
//! simulator and compensation.

use serde::{Deserialize, Serialize};

/// A position in the stage frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct XyUm {
    /// x, µm.
    pub x_um: f64,
    /// y, µm.
    pub y_um: f64,
}

impl From<[f64; 2]> for XyUm {
    fn from(v: [f64; 2]) -> Self {
        XyUm {
            x_um: v[0],
            y_um: v[1],
        }
    }
}
