//! The [`Term`] trait every error contribution implements, and the registry
//! that maps a model file's `kind = "..."` to the code that builds the term.
//!
//! Adding a term: write one struct implementing [`Term`] (plus a config struct
//! with `#[serde(deny_unknown_fields)]`), give it a builder function, and
//! register it with [`TermRegistry::register`]. Model files then select it by
//! its kind name; fitting, TOML round trip and parameter listing work without
//! further changes.

use std::collections::BTreeMap;
use std::fmt;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::state::MotionState;
use super::ModelError;

/// What a term moves: the platform itself, or only where the camera sees it.
///
/// Why the distinction: the simulator must put the platform where the stage
/// puts it and let the camera see it shifted; the analysis only ever sees the
/// sum. [`crate::model::StageModel::true_position`] sums `Platform` terms,
/// [`crate::model::StageModel::observed_position`] sums all terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Effect {
    /// Moves the platform (the tool point) in the stage frame.
    Platform,
    /// Shifts the camera's view only (e.g. thermal drift of the microscope).
    Observation,
}

/// Description of one parameter of a term, for people and for fitting.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamInfo {
    /// Parameter name, unique within its term (e.g. `forward_sin_1_um`).
    pub name: String,
    /// Unit (e.g. `µm`, `µrad`, `ppm`, `µm/°C`).
    pub unit: &'static str,
    /// Current value, in `unit`.
    pub value: f64,
    /// Short physical explanation.
    pub doc: String,
}

impl ParamInfo {
    /// Convenience constructor.
    pub fn new(
        name: impl Into<String>,
        unit: &'static str,
        value: f64,
        doc: impl Into<String>,
    ) -> Self {
        ParamInfo {
            name: name.into(),
            unit,
            value,
            doc: doc.into(),
        }
    }
}

/// One additive contribution to the stage's position error.
///
/// Sign convention (the one of the whole model): a contribution `[dx, dy]`
/// (µm) is added to the commanded position, `true_um = cmd_um + Σ
/// contributions`. The paper's error `e = target − measured` is therefore
/// `−Σ contributions` when the stage was commanded to the target.
///
/// Implementations must return finite values for every finite, validated
/// [`MotionState`] and never panic.
pub trait Term: fmt::Debug + Send + Sync {
    /// Instance name from the model file, unique in a model (e.g. `x_cyclic`).
    fn name(&self) -> &str;

    /// Registered kind (e.g. `leadscrew_cyclic`).
    fn kind(&self) -> &'static str;

    /// What the term moves; platform by default.
    fn effect(&self) -> Effect {
        Effect::Platform
    }

    /// Parameters with their current values, in a fixed order (the order of
    /// [`Term::set_params`] and [`Term::jacobian`]).
    fn params(&self) -> Vec<ParamInfo>;

    /// Sets all parameters in [`Term::params`] order. Must reject a wrong
    /// count or non-finite values (see [`check_param_values`]) and leave the
    /// term unchanged then.
    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError>;

    /// Contribution `[dx_um, dy_um]` at `state`.
    fn contribution(&self, state: &MotionState) -> [f64; 2];

    /// The platform's rotation about +z this term causes at `state`, rad:
    /// right-handed in the stage frame (positive turns +x towards +y,
    /// counter-clockwise seen from above); 0 for a term that only
    /// translates (the default). Why a term says it: a camera looking at a
    /// pattern on the platform sees this rotation (the decoded θ), while
    /// [`Term::contribution`] is only the displacement it gives the
    /// observed point. Pitch and roll tilt the platform out of the plane:
    /// an in-plane pattern cannot see them, so they report 0 here.
    fn yaw_rad(&self, _state: &MotionState) -> f64 {
        0.0
    }

    /// True when the contribution is linear in the parameters (the jacobian
    /// does not depend on them): a fit of only such terms is one linear solve.
    fn is_linear(&self) -> bool {
        false
    }

    /// ∂contribution/∂parameter, one `[∂dx, ∂dy]` per parameter in
    /// [`Term::params`] order. The default is a central difference; linear
    /// terms override it with the exact value.
    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        numeric_jacobian(self, state)
    }

    /// The term's model-file table, without `kind` (the model adds it). Must
    /// round-trip through the term's builder.
    fn to_config(&self) -> Result<toml::Table, ModelError>;

    /// Boxed copy (terms live in `Box<dyn Term>`).
    fn clone_box(&self) -> Box<dyn Term>;
}

impl Clone for Box<dyn Term> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

/// Central-difference jacobian of any term, the default of
/// [`Term::jacobian`]. The step is `1e-6 · max(1, |p|)` in the parameter's
/// unit, which is exact for piecewise-linear dependence away from kinks.
pub fn numeric_jacobian<T: Term + ?Sized>(term: &T, state: &MotionState) -> Vec<[f64; 2]> {
    let p0: Vec<f64> = term.params().iter().map(|p| p.value).collect();
    let mut probe = term.clone_box();
    let mut out = Vec::with_capacity(p0.len());
    let mut p = p0.clone();
    for i in 0..p0.len() {
        let h = 1e-6 * p0[i].abs().max(1.0);
        p[i] = p0[i] + h;
        let plus = probe
            .set_params(&p)
            .map(|()| probe.contribution(state))
            .unwrap_or([0.0; 2]);
        p[i] = p0[i] - h;
        let minus = probe
            .set_params(&p)
            .map(|()| probe.contribution(state))
            .unwrap_or([0.0; 2]);
        p[i] = p0[i];
        out.push([
            (plus[0] - minus[0]) / (2.0 * h),
            (plus[1] - minus[1]) / (2.0 * h),
        ]);
    }
    out
}

/// Checks a `set_params` argument: right count, all finite and within
/// [`MAX_PARAM_MAGNITUDE`]. Terms call it first thing.
pub fn check_param_values(term: &str, expected: usize, values: &[f64]) -> Result<(), ModelError> {
    if values.len() != expected {
        return Err(ModelError::ParamCount {
            term: term.to_string(),
            expected,
            got: values.len(),
        });
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(ModelError::NonFinite {
            what: format!("parameter {i} of term `{term}`"),
        });
    }
    if let Some(i) = values.iter().position(|v| v.abs() > MAX_PARAM_MAGNITUDE) {
        return Err(ModelError::Invalid {
            key: format!("parameter {i} of term `{term}`"),
            reason: format!(
                "{} is implausibly large (limit ±{MAX_PARAM_MAGNITUDE:e})",
                values[i]
            ),
        });
    }
    Ok(())
}

/// Largest magnitude any term parameter or config number may have, in its
/// own unit. Far beyond anything physical (1e12 µm is 1000 km), it keeps
/// every contribution finite for states within [`MAX_POSITION_UM`].
///
/// [`MAX_POSITION_UM`]: super::state::MAX_POSITION_UM
pub const MAX_PARAM_MAGNITUDE: f64 = 1e12;

/// Deserializes a term's table into its config struct, turning serde's
/// message (which names the offending key) into a [`ModelError::Term`].
pub fn parse_term_config<C: DeserializeOwned>(
    name: &str,
    kind: &str,
    table: toml::Table,
) -> Result<C, ModelError> {
    // Going through text (rather than `Value::try_into`) keeps the span of a
    // bad value, so the message can quote the offending `key = value`.
    let text = toml::to_string(&table).map_err(|e| ModelError::Serialize {
        what: format!("term `{name}`"),
        message: e.to_string(),
    })?;
    toml::from_str(&text).map_err(|e: toml::de::Error| {
        let at = e
            .span()
            .and_then(|s| {
                let start = text.get(..s.start)?.rfind('\n').map_or(0, |i| i + 1);
                let end = text
                    .get(s.start..)?
                    .find('\n')
                    .map_or(text.len(), |i| s.start + i);
                text.get(start..end)
            })
            .map(str::trim)
            .filter(|l| !l.is_empty());
        let message = e.message().trim().to_string();
        // A missing field has the whole table as its span: no line to quote.
        let at = at.filter(|_| !message.starts_with("missing field"));
        ModelError::Term {
            term: name.to_string(),
            kind: kind.to_string(),
            message: match at {
                Some(line) => format!("at `{line}`: {message}"),
                None => message,
            },
        }
    })
}

/// Serializes a term's config struct into its model-file table.
pub fn config_table<C: Serialize>(name: &str, config: &C) -> Result<toml::Table, ModelError> {
    toml::Table::try_from(config).map_err(|e| ModelError::Serialize {
        what: format!("term `{name}`"),
        message: e.to_string(),
    })
}

/// Validation helper: `value` must be finite. `key` names the offending key
/// in the error (e.g. `forward_sin_um[1]`).
pub fn require_finite(term: &str, key: &str, value: f64) -> Result<f64, ModelError> {
    if !value.is_finite() {
        Err(ModelError::Invalid {
            key: format!("term `{term}`: {key}"),
            reason: format!("must be a finite number, got {value}"),
        })
    } else if value.abs() > MAX_PARAM_MAGNITUDE {
        Err(ModelError::Invalid {
            key: format!("term `{term}`: {key}"),
            reason: format!("{value} is implausibly large (limit ±{MAX_PARAM_MAGNITUDE:e})"),
        })
    } else {
        Ok(value)
    }
}

/// Validation helper: `value` must be finite and > 0.
pub fn require_positive(term: &str, key: &str, value: f64) -> Result<f64, ModelError> {
    require_finite(term, key, value)?;
    if value > 0.0 {
        Ok(value)
    } else {
        Err(ModelError::Invalid {
            key: format!("term `{term}`: {key}"),
            reason: format!("must be > 0, got {value}"),
        })
    }
}

/// Validation helper: `value` must be finite and ≥ 0.
pub fn require_non_negative(term: &str, key: &str, value: f64) -> Result<f64, ModelError> {
    require_finite(term, key, value)?;
    if value >= 0.0 {
        Ok(value)
    } else {
        Err(ModelError::Invalid {
            key: format!("term `{term}`: {key}"),
            reason: format!("must be ≥ 0, got {value}"),
        })
    }
}

/// Builds a term from its instance name and its model-file table (without
/// `name` and `kind`).
pub type TermBuilder = fn(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError>;

/// Maps kind names to builders. [`TermRegistry::builtin`] knows every term in
/// [`crate::model::terms`]; an analysis that invents a new term registers it
/// on top.
#[derive(Clone)]
pub struct TermRegistry {
    /// Kind → (builder, one-line doc); `terms` fills it with the built-in
    /// kinds ([`TermRegistry::builtin`]).
    pub(super) kinds: BTreeMap<String, (TermBuilder, &'static str)>,
}

impl fmt::Debug for TermRegistry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.kinds.keys()).finish()
    }
}

impl TermRegistry {
    /// A registry without any kind.
    pub fn empty() -> Self {
        TermRegistry {
            kinds: BTreeMap::new(),
        }
    }

    /// Adds a kind. Refuses to replace an existing one (two terms answering
    /// to one name would make model files ambiguous).
    pub fn register(
        &mut self,
        kind: &str,
        doc: &'static str,
        builder: TermBuilder,
    ) -> Result<(), ModelError> {
        if self.kinds.contains_key(kind) {
            return Err(ModelError::DuplicateKind {
                kind: kind.to_string(),
            });
        }
        self.kinds.insert(kind.to_string(), (builder, doc));
        Ok(())
    }

    /// Registered kinds with their one-line documentation.
    pub fn kinds(&self) -> impl Iterator<Item = (&str, &'static str)> {
        self.kinds.iter().map(|(k, (_, d))| (k.as_str(), *d))
    }

    /// Builds a term of `kind`.
    pub fn build(
        &self,
        kind: &str,
        name: &str,
        table: toml::Table,
    ) -> Result<Box<dyn Term>, ModelError> {
        let (builder, _) = self
            .kinds
            .get(kind)
            .ok_or_else(|| ModelError::UnknownKind {
                term: name.to_string(),
                kind: kind.to_string(),
                known: self.kinds.keys().cloned().collect::<Vec<_>>().join(", "),
            })?;
        builder(name, table)
    }
}

impl Default for TermRegistry {
    fn default() -> Self {
        TermRegistry::builtin()
    }
}
