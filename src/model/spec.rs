//! Declarative model-term parameters: a term's fit parameters declared once
//! (TOML key, unit, accepted range, description, how to read and write the
//! value, Jacobian column) and read by the model-file checks, the parameter
//! list of reports and fits, `set_params` and the Jacobian.
//!
//! Why: without it every term hand-writes four pieces that must agree with
//! each other (a key checked but not listed, or listed in a different order
//! than `set_params` writes, is a silent fit error). A term
//! whose parameters are all scalars of its configuration is a [`TermSpec`]:
//! its configuration struct (serde, `deny_unknown_fields`), a table of
//! [`ParamSpec`] (one `param!` line each: the key is the field's name) and
//! its contribution; [`SpecTerm`] is its [`Term`].

use std::fmt;

use serde::de::DeserializeOwned;
use serde::Serialize;

use super::state::MotionState;
use super::term::{
    check_param_values, config_table, numeric_jacobian, parse_term_config, require_finite,
    require_non_negative, require_positive, Effect, ParamInfo, Term,
};
use super::ModelError;

/// The values a model file may give a parameter (a fit may still move it
/// anywhere finite: the range is a statement about physical stages, not a
/// constraint of the optimiser).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamRange {
    /// Any finite value within ±[`super::MAX_PARAM_MAGNITUDE`].
    Finite,
    /// Finite and ≥ 0.
    NonNegative,
    /// Finite and > 0.
    Positive,
}

/// One scalar fit parameter of a term's configuration `C`.
pub struct ParamSpec<C> {
    /// TOML key in the term's table, and the parameter's name in fits and
    /// reports; carries the unit suffix (`_um`, `_urad`, …).
    pub key: &'static str,
    /// Unit for display.
    pub unit: &'static str,
    /// What a model file may give.
    pub range: ParamRange,
    /// Reads the value from the configuration.
    pub get: fn(&C) -> f64,
    /// Writes the value into the configuration.
    pub set: fn(&mut C, f64),
    /// What the parameter means for this configuration (for reports).
    pub doc: fn(&C) -> String,
    /// ∂contribution/∂parameter (µm per unit) when the contribution is
    /// linear in this parameter; `None` for a non-linear one (then the
    /// term's Jacobian is numeric).
    pub column: Option<fn(&C, &MotionState) -> [f64; 2]>,
}

/// Declares one [`ParamSpec`] from a scalar field of the term's
/// configuration: `param!(field, "unit", Range, doc, column)`.
///
/// Why a macro: the TOML key is the field's name (`stringify!`), which is
/// also the name serde reads and writes, and the getter and setter are that
/// field; so key, getter and setter cannot disagree, and a term declares
/// only what is particular to each parameter. `doc` is a string literal or
/// a `fn(&Config) -> String`; `column` is `linear(|cfg, state| …)` (the
/// Jacobian column, µm per unit) or `nonlinear`.
macro_rules! param {
    ($field:ident, $unit:literal, $range:ident, $doc:literal, $($column:tt)+) => {
        $crate::model::spec::param!(@spec $field, $unit, $range, |_| ::std::string::String::from($doc), $($column)+)
    };
    ($field:ident, $unit:literal, $range:ident, $doc:expr, $($column:tt)+) => {
        $crate::model::spec::param!(@spec $field, $unit, $range, $doc, $($column)+)
    };
    (@spec $field:ident, $unit:literal, $range:ident, $doc:expr, linear($column:expr)) => {
        $crate::model::spec::param!(@build $field, $unit, $range, $doc, Some($column))
    };
    (@spec $field:ident, $unit:literal, $range:ident, $doc:expr, nonlinear) => {
        $crate::model::spec::param!(@build $field, $unit, $range, $doc, None)
    };
    (@build $field:ident, $unit:literal, $range:ident, $doc:expr, $column:expr) => {
        $crate::model::spec::ParamSpec {
            key: stringify!($field),
            unit: $unit,
            range: $crate::model::spec::ParamRange::$range,
            get: |c| c.$field,
            set: |c, v| c.$field = v,
            doc: $doc,
            column: $column,
        }
    };
}
pub(crate) use param;

impl<C> fmt::Debug for ParamSpec<C> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ParamSpec")
            .field("key", &self.key)
            .field("unit", &self.unit)
            .field("range", &self.range)
            .field("linear", &self.column.is_some())
            .finish()
    }
}

/// Checks every declared parameter of `cfg` against its range, in table
/// order; the error names the term and the key.
pub fn check_params<C>(term: &str, specs: &[ParamSpec<C>], cfg: &C) -> Result<(), ModelError> {
    for s in specs {
        let v = (s.get)(cfg);
        match s.range {
            ParamRange::Finite => require_finite(term, s.key, v)?,
            ParamRange::NonNegative => require_non_negative(term, s.key, v)?,
            ParamRange::Positive => require_positive(term, s.key, v)?,
        };
    }
    Ok(())
}

/// The declared parameters of `cfg` with their current values, in table
/// order.
pub fn param_infos<C>(specs: &[ParamSpec<C>], cfg: &C) -> Vec<ParamInfo> {
    specs
        .iter()
        .map(|s| ParamInfo::new(s.key, s.unit, (s.get)(cfg), (s.doc)(cfg)))
        .collect()
}

/// Writes `values` (one per declared parameter, in table order) into `cfg`
/// after checking their count and finiteness.
pub fn set_param_values<C>(
    term: &str,
    specs: &[ParamSpec<C>],
    cfg: &mut C,
    values: &[f64],
) -> Result<(), ModelError> {
    check_param_values(term, specs.len(), values)?;
    for (s, &v) in specs.iter().zip(values) {
        (s.set)(cfg, v);
    }
    Ok(())
}

/// A term kind whose fit parameters are all declared scalars of its
/// configuration: adding such a kind is one file with its configuration,
/// this impl and a `build` entry in the registry.
pub trait TermSpec: fmt::Debug + Clone + PartialEq + Send + Sync + 'static {
    /// The term's model-file table.
    type Config: fmt::Debug + Clone + PartialEq + Serialize + DeserializeOwned + Send + Sync;
    /// Kind name in model files.
    const KIND: &'static str;
    /// Where the contribution acts (the platform, or only what the camera
    /// sees).
    const EFFECT: Effect = Effect::Platform;
    /// The fit parameters, in the order of [`Term::params`].
    const PARAMS: &'static [ParamSpec<Self::Config>];
    /// Checks beyond the parameter ranges (none by default).
    fn check(_name: &str, _cfg: &Self::Config) -> Result<(), ModelError> {
        Ok(())
    }
    /// The term's error contribution (µm, x and y) in `state`.
    fn contribution(cfg: &Self::Config, state: &MotionState) -> [f64; 2];
    /// The platform's yaw the term causes, rad ([`Term::yaw_rad`]; none by
    /// default).
    fn yaw_rad(_cfg: &Self::Config, _state: &MotionState) -> f64 {
        0.0
    }
}

/// The [`Term`] of a [`TermSpec`] kind: a name and a checked configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct SpecTerm<D: TermSpec> {
    name: String,
    cfg: D::Config,
}

impl<D: TermSpec> SpecTerm<D> {
    /// Builds and validates (every declared range, then [`TermSpec::check`]).
    pub fn new(name: &str, cfg: D::Config) -> Result<Self, ModelError> {
        check_params(name, D::PARAMS, &cfg)?;
        D::check(name, &cfg)?;
        Ok(SpecTerm {
            name: name.to_string(),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &D::Config {
        &self.cfg
    }

    /// The registry's builder: parses the table (naming the term and kind in
    /// errors) and validates.
    pub(crate) fn build(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
        let cfg = parse_term_config(name, D::KIND, table)?;
        Ok(Box::new(Self::new(name, cfg)?))
    }
}

impl<D: TermSpec> Term for SpecTerm<D> {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        D::KIND
    }

    fn effect(&self) -> Effect {
        D::EFFECT
    }

    fn params(&self) -> Vec<ParamInfo> {
        param_infos(D::PARAMS, &self.cfg)
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        set_param_values(&self.name, D::PARAMS, &mut self.cfg, values)
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        D::contribution(&self.cfg, state)
    }

    fn yaw_rad(&self, state: &MotionState) -> f64 {
        D::yaw_rad(&self.cfg, state)
    }

    fn is_linear(&self) -> bool {
        D::PARAMS.iter().all(|s| s.column.is_some())
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        if self.is_linear() {
            D::PARAMS
                .iter()
                .map(|s| s.column.map_or([0.0; 2], |col| col(&self.cfg, state)))
                .collect()
        } else {
            numeric_jacobian(self, state)
        }
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
    use super::super::state::Axis;
    use super::super::terms::{
        BacklashConfig, BacklashTerm, LeadConfig, LeadTerm, OriginOffsetConfig, OriginOffsetTerm,
        SquarenessConfig, SquarenessTerm,
    };
    use super::*;

    fn terms() -> Vec<Box<dyn Term>> {
        vec![
            Box::new(
                LeadTerm::new(
                    "l",
                    LeadConfig {
                        axis: Axis::Y,
                        ppm: 120.0,
                    },
                )
                .unwrap(),
            ),
            Box::new(SquarenessTerm::new("s", SquarenessConfig { angle_urad: -40.0 }).unwrap()),
            Box::new(
                OriginOffsetTerm::new(
                    "o",
                    OriginOffsetConfig {
                        x_um: 1.5,
                        y_um: -2.0,
                    },
                )
                .unwrap(),
            ),
            Box::new(
                BacklashTerm::new(
                    "b",
                    BacklashConfig {
                        axis: Axis::X,
                        backlash_um: 2.0,
                    },
                )
                .unwrap(),
            ),
        ]
    }

    #[test]
    fn every_parameter_is_a_key_of_the_model_file_table() {
        for t in terms() {
            let table = t.to_config().unwrap();
            for p in t.params() {
                let v = table.get(&p.name).and_then(toml::Value::as_float);
                assert_eq!(v, Some(p.value), "{}: {}", t.kind(), p.name);
            }
        }
    }

    #[test]
    fn set_params_writes_in_the_declared_order() {
        for mut t in terms() {
            let n = t.params().len();
            let values: Vec<f64> = (0..n).map(|i| 0.25 + i as f64).collect();
            t.set_params(&values).unwrap();
            let got: Vec<f64> = t.params().iter().map(|p| p.value).collect();
            assert_eq!(got, values, "{}", t.kind());
            assert!(t.set_params(&values[1..]).is_err(), "{}", t.kind());
        }
    }

    #[test]
    fn declared_columns_match_the_numeric_jacobian() {
        let state = MotionState::at_rest(3000.0, -7000.0);
        for t in terms().into_iter().filter(|t| t.is_linear()) {
            let exact = t.jacobian(&state);
            let numeric = numeric_jacobian(t.as_ref(), &state);
            assert_eq!(exact.len(), numeric.len(), "{}", t.kind());
            for (e, n) in exact.iter().zip(&numeric) {
                for k in 0..2 {
                    assert!((e[k] - n[k]).abs() < 1e-9, "{}: {e:?} vs {n:?}", t.kind());
                }
            }
        }
    }

    #[test]
    fn ranges_are_checked_with_the_key_named() {
        let err = BacklashTerm::new(
            "b",
            BacklashConfig {
                axis: Axis::X,
                backlash_um: -1.0,
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("backlash_um"), "{err}");
        let err = LeadTerm::new(
            "l",
            LeadConfig {
                axis: Axis::X,
                ppm: f64::INFINITY,
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("ppm"), "{err}");
    }
}
