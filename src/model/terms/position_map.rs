//! An error map over x and y: one error component tabulated at the nodes of
//! a lattice, bilinear between them, optionally one layer per arrival
//! direction of that component's axis.
//!
//! Why a term of its own: every other term is a function of one position
//! (or a product of two, `stacked_yaw`), so their sum is a separable
//! `f(x) + g(y)` plus a few named interactions. A real stage's map can hold
//! joint x–y structure that no named cause explains (a wafer stage's y
//! error whose slope along x changes across y; a guide's twist; a zone
//! stitched from two set-ups). `micropos diagnose` fits this term on grid
//! logs when it predicts held-out cells better than the model without it,
//! so the extended model, and the simulator that runs it, carry the
//! measured map like any other term.
//!
//! ```text
//! v(x, y) = Σ_{ix, iy} w_ix(x)·w_iy(y)·V[iy·nx + ix]      (hat weights)
//! component = x:  [dx, dy] = [v, 0];   component = y:  [0, v]
//! ```
//!
//! Beyond the lattice the edge values hold (no extrapolation, as
//! `position_table`). With `from_above_um`, the layer follows the last
//! direction of the component's own axis: `values_um` for arrivals from
//! below (forward), `from_above_um` from above (backward), their mean when
//! the direction is unknown. Sign: the model's (`true = cmd + Σ`), so a
//! node value is the error `measured − target` a log shows there, µm.
//! Linear in every node value.

use serde::{Deserialize, Serialize};

use super::super::error::ModelError;
use super::super::state::{Axis, Direction, MotionState};
use super::super::term::{check_param_values, config_table, parse_term_config, ParamInfo, Term};
use super::discovered::table_weights;

/// Kind name.
pub const KIND: &str = "position_map";

/// Most nodes a layer may have (a 1000 × 1000 map): a bound on what a
/// model file can make the model allocate per evaluation of its
/// parameter list.
pub const MAX_NODES: usize = 1_000_000;

/// Model-file table of a position map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionMapConfig {
    /// The error component the map moves.
    pub component: Axis,
    /// Lattice columns: commanded x of the nodes, µm, strictly increasing
    /// (≥ 2).
    pub xs_um: Vec<f64>,
    /// Lattice rows: commanded y of the nodes, µm, strictly increasing
    /// (≥ 2).
    pub ys_um: Vec<f64>,
    /// Node values, µm, row-major (`values_um[iy·nx + ix]`): the layer of
    /// arrivals from below on the component's axis, or the only layer.
    pub values_um: Vec<f64>,
    /// Node values for arrivals from above (same layout), when the map was
    /// measured both ways.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_above_um: Option<Vec<f64>>,
}

impl PositionMapConfig {
    /// Columns and rows of the lattice.
    pub fn shape(&self) -> (usize, usize) {
        (self.xs_um.len(), self.ys_um.len())
    }

    fn check(&self, name: &str) -> Result<(), ModelError> {
        let bad = |key: &str, reason: String| ModelError::Invalid {
            key: format!("term `{name}`: {key}"),
            reason,
        };
        for (key, knots) in [("xs_um", &self.xs_um), ("ys_um", &self.ys_um)] {
            if knots.len() < 2 {
                return Err(bad(
                    key,
                    format!("needs at least 2 nodes, got {}", knots.len()),
                ));
            }
            if let Some(i) = knots
                .iter()
                .position(|v| !(v.is_finite() && v.abs() <= 1e9))
            {
                return Err(bad(
                    &format!("{key}[{i}]"),
                    format!("must be finite, |v| ≤ 1e9 µm, got {}", knots[i]),
                ));
            }
            if let Some(i) = knots.windows(2).position(|w| w[1] <= w[0]) {
                return Err(bad(
                    &format!("{key}[{}]", i + 1),
                    format!(
                        "nodes must be strictly increasing: {} after {}",
                        knots[i + 1],
                        knots[i]
                    ),
                ));
            }
        }
        let (nx, ny) = self.shape();
        let nodes = nx.saturating_mul(ny);
        if nodes > MAX_NODES {
            return Err(bad(
                "xs_um × ys_um",
                format!("{nx} × {ny} nodes is more than the {MAX_NODES} a map may have"),
            ));
        }
        let layers = [
            ("values_um", Some(&self.values_um)),
            ("from_above_um", self.from_above_um.as_ref()),
        ];
        for (key, layer) in layers {
            let Some(layer) = layer else { continue };
            if layer.len() != nodes {
                return Err(bad(
                    key,
                    format!(
                        "has {} values; a {nx} × {ny} lattice needs {nodes} (row-major, x fastest)",
                        layer.len()
                    ),
                ));
            }
            check_param_values(name, nodes, layer)?;
        }
        Ok(())
    }

    /// The nodes and hat weights around `(x, y)`: `[(node, weight); 4]`.
    fn weights(&self, x_um: f64, y_um: f64) -> Option<[(usize, f64); 4]> {
        let (kx, wx) = table_weights(&self.xs_um, x_um)?;
        let (ky, wy) = table_weights(&self.ys_um, y_um)?;
        let nx = self.xs_um.len();
        let at = |ix: usize, iy: usize| iy * nx + ix;
        Some([
            (at(kx, ky), (1.0 - wx) * (1.0 - wy)),
            (at(kx + 1, ky), wx * (1.0 - wy)),
            (at(kx, ky + 1), (1.0 - wx) * wy),
            (at(kx + 1, ky + 1), wx * wy),
        ])
    }

    /// Weight of each layer at `state`: `[below, above]` (the one layer of
    /// a one-way map takes every direction).
    fn layer_weights(&self, state: &MotionState) -> [f64; 2] {
        if self.from_above_um.is_none() {
            return [1.0, 0.0];
        }
        match state.axis(self.component).dir {
            Direction::Forward => [1.0, 0.0],
            Direction::Backward => [0.0, 1.0],
            Direction::Unknown => [0.5, 0.5],
        }
    }

    /// The map's value at `state`, µm.
    pub fn value_um(&self, state: &MotionState) -> f64 {
        let Some(w) = self.weights(state.cmd_um(Axis::X), state.cmd_um(Axis::Y)) else {
            return 0.0;
        };
        let lw = self.layer_weights(state);
        let at = |layer: &[f64]| -> f64 {
            w.iter()
                .map(|&(k, wk)| wk * layer.get(k).copied().unwrap_or(0.0))
                .sum()
        };
        let mut v = lw[0] * at(&self.values_um);
        if let Some(above) = &self.from_above_um {
            v += lw[1] * at(above);
        }
        v
    }

    fn place(&self, v: f64) -> [f64; 2] {
        match self.component {
            Axis::X => [v, 0.0],
            Axis::Y => [0.0, v],
        }
    }
}

/// The position-map term.
#[derive(Debug, Clone, PartialEq)]
pub struct PositionMapTerm {
    name: String,
    cfg: PositionMapConfig,
}

impl PositionMapTerm {
    /// A checked term.
    pub fn new(name: &str, cfg: PositionMapConfig) -> Result<Self, ModelError> {
        cfg.check(name)?;
        Ok(PositionMapTerm {
            name: name.to_string(),
            cfg,
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &PositionMapConfig {
        &self.cfg
    }

    /// Builder for the registry.
    pub fn build(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
        let cfg: PositionMapConfig = parse_term_config(name, KIND, table)?;
        Ok(Box::new(PositionMapTerm::new(name, cfg)?))
    }
}

impl Term for PositionMapTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        let c = &self.cfg;
        let nx = c.xs_um.len();
        let node = |prefix: &str, way: &str, k: usize, v: f64| {
            let (ix, iy) = (k % nx, k / nx);
            ParamInfo::new(
                format!("{prefix}_{ix}_{iy}_um"),
                "µm",
                v,
                format!(
                    "{} error at (x, y) = ({}, {}) µm{way}",
                    c.component,
                    c.xs_um.get(ix).copied().unwrap_or(f64::NAN),
                    c.ys_um.get(iy).copied().unwrap_or(f64::NAN),
                ),
            )
        };
        let below_way = if c.from_above_um.is_some() {
            ", arriving from below"
        } else {
            ""
        };
        let mut out: Vec<ParamInfo> = c
            .values_um
            .iter()
            .enumerate()
            .map(|(k, &v)| node("node", below_way, k, v))
            .collect();
        if let Some(above) = &c.from_above_um {
            out.extend(
                above
                    .iter()
                    .enumerate()
                    .map(|(k, &v)| node("above", ", arriving from above", k, v)),
            );
        }
        out
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        let n = self.cfg.values_um.len();
        let layers = 1 + usize::from(self.cfg.from_above_um.is_some());
        check_param_values(&self.name, n * layers, values)?;
        let (below, above) = values.split_at(n);
        self.cfg.values_um.copy_from_slice(below);
        if let Some(a) = &mut self.cfg.from_above_um {
            a.copy_from_slice(above);
        }
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        self.cfg.place(self.cfg.value_um(state))
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        let n = self.cfg.values_um.len();
        let layers = 1 + usize::from(self.cfg.from_above_um.is_some());
        let mut out = vec![[0.0; 2]; n * layers];
        let Some(w) = self
            .cfg
            .weights(state.cmd_um(Axis::X), state.cmd_um(Axis::Y))
        else {
            return out;
        };
        let lw = self.cfg.layer_weights(state);
        for (layer, &l) in lw.iter().enumerate().take(layers) {
            for &(k, wk) in &w {
                if let Some(j) = out.get_mut(layer * n + k) {
                    let add = self.cfg.place(l * wk);
                    j[0] += add[0];
                    j[1] += add[1];
                }
            }
        }
        out
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::term::numeric_jacobian;
    use crate::model::StageModel;

    fn map(component: Axis, above: bool) -> PositionMapTerm {
        PositionMapTerm::new(
            "m",
            PositionMapConfig {
                component,
                xs_um: vec![0.0, 100.0, 300.0],
                ys_um: vec![0.0, 200.0],
                values_um: vec![0.0, 1.0, 3.0, 2.0, 4.0, -1.0],
                from_above_um: above.then(|| vec![10.0; 6]),
            },
        )
        .unwrap()
    }

    #[test]
    fn bilinear_between_nodes_and_held_beyond() {
        let t = map(Axis::Y, false);
        let at = |x, y| t.contribution(&MotionState::at_rest(x, y));
        // Nodes give their values.
        assert_eq!(at(100.0, 0.0), [0.0, 1.0]);
        assert_eq!(at(300.0, 200.0), [0.0, -1.0]);
        // Halfway along x between (0,0)=0 and (100,0)=1, and along y.
        assert!((at(50.0, 0.0)[1] - 0.5).abs() < 1e-12);
        // Centre of the first cell: mean of 0, 1, 2, 4.
        assert!((at(50.0, 100.0)[1] - 1.75).abs() < 1e-12);
        // Beyond the lattice the edge values hold.
        assert_eq!(at(-500.0, -500.0), [0.0, 0.0]);
        assert_eq!(at(900.0, 900.0), [0.0, -1.0]);
        let tx = map(Axis::X, false);
        assert_eq!(
            tx.contribution(&MotionState::at_rest(100.0, 0.0)),
            [1.0, 0.0]
        );
    }

    #[test]
    fn the_layer_follows_the_components_axis() {
        let t = map(Axis::X, true);
        let s = |xd, yd| MotionState::arrived(100.0, xd, 0.0, yd);
        use Direction::{Backward as B, Forward as F, Unknown as U};
        assert_eq!(t.contribution(&s(F, B))[0], 1.0);
        assert_eq!(t.contribution(&s(B, F))[0], 10.0);
        assert_eq!(t.contribution(&s(U, F))[0], 5.5);
    }

    #[test]
    fn exact_jacobian_matches_the_numeric_one_and_params_round_trip() {
        for above in [false, true] {
            let mut t = map(Axis::Y, above);
            let s = MotionState::arrived(170.0, Direction::Backward, 60.0, Direction::Unknown);
            let (a, b) = (t.jacobian(&s), numeric_jacobian(&t, &s));
            assert_eq!(a.len(), b.len());
            for (p, q) in a.iter().zip(&b) {
                assert!(
                    (p[0] - q[0]).abs() < 1e-6 && (p[1] - q[1]).abs() < 1e-6,
                    "{p:?} {q:?}"
                );
            }
            let v: Vec<f64> = t.params().iter().map(|p| p.value + 1.0).collect();
            t.set_params(&v).unwrap();
            assert_eq!(t.params().iter().map(|p| p.value).collect::<Vec<_>>(), v);
            assert!(t.set_params(&v[1..]).is_err());
        }
    }

    #[test]
    fn model_file_round_trip_and_bad_tables_named() {
        let mut m = StageModel::ideal();
        m.push_term(Box::new(map(Axis::Y, true))).unwrap();
        let text = m.to_toml().unwrap();
        let back = StageModel::from_toml(&text).unwrap();
        assert_eq!(back.parameter_vector(), m.parameter_vector());
        let s = MotionState::at_rest(50.0, 100.0);
        assert_eq!(back.observed_error_um(&s), m.observed_error_um(&s));
        let bad = |from: &str, to: &str| {
            let t = text.replacen(from, to, 1);
            assert_ne!(t, text, "{from} not in the file");
            StageModel::from_toml(&t).unwrap_err().to_string()
        };
        assert!(
            bad("xs_um = [0.0, 100.0, 300.0]", "xs_um = [0.0, 300.0, 100.0]")
                .contains("strictly increasing")
        );
        assert!(bad("ys_um = [0.0, 200.0]", "ys_um = [0.0]").contains("at least 2"));
        assert!(bad(
            "values_um = [0.0, 1.0, 3.0, 2.0, 4.0, -1.0]",
            "values_um = [0.0]"
        )
        .contains("needs 6"));
        assert!(bad("component = \"y\"", "component = \"z\"").contains("component"));
    }
}
