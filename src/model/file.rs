//! The model file (TOML): format, the non-term sections, loading and saving.
//!
//! ```toml
//! format_version = 1
//! description = "..."
//! [stochastic]          # what the simulator adds that is not systematic
//! [environment]         # ambient temperature history
//! [[term]]              # one table per error term: kind, name, then the
//! kind = "backlash"     # kind's own keys
//! name = "x_backlash"
//! axis = "x"
//! backlash_um = 2.0
//! ```
//! Unknown keys anywhere are errors naming the key; non-finite numbers (TOML
//! has `nan` and `inf`) are errors naming the key.

use serde::{Deserialize, Serialize};

use super::env::{Environment, Stochastic};
use super::error::ModelError;
use super::stage::StageModel;
use super::term::TermRegistry;

/// The only format version this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// The documented default model file (PI M-111.1DG stack of the paper).
pub const PAPER_DEFAULT_TOML: &str = include_str!("../../config/stage-model.toml");

/// The paper-faithful model file: the default plus the effects that make
/// the paper's own procedure land on the paper's measured figures
/// (docs/design/paper-faithful.md). Compiled in because it is the stage the
/// main job simulates by default: the figures a user reproduces should be
/// measured on the stage the paper measured, not a kinder one.
pub const PAPER_FAITHFUL_TOML: &str = include_str!("../../config/stage-model-paper.toml");

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelFile {
    format_version: u32,
    #[serde(default)]
    description: String,
    #[serde(default)]
    stochastic: Stochastic,
    #[serde(default)]
    environment: Environment,
    #[serde(default)]
    term: Vec<toml::Table>,
}

fn take_string(table: &mut toml::Table, index: usize, key: &str) -> Result<String, ModelError> {
    match table.remove(key) {
        Some(toml::Value::String(s)) => Ok(s),
        Some(other) => Err(ModelError::Invalid {
            key: format!("term[{index}].{key}"),
            reason: format!("must be a string, got {}", other.type_str()),
        }),
        None => Err(ModelError::Invalid {
            key: format!("term[{index}].{key}"),
            reason: "missing".into(),
        }),
    }
}

pub(crate) fn parse(text: &str, registry: &TermRegistry) -> Result<StageModel, ModelError> {
    let file: ModelFile = toml::from_str(text).map_err(|e| ModelError::Toml {
        message: e.to_string().trim().to_string(),
    })?;
    if file.format_version != FORMAT_VERSION {
        return Err(ModelError::Invalid {
            key: "format_version".into(),
            reason: format!(
                "this micropos reads version {FORMAT_VERSION}, the file says {}",
                file.format_version
            ),
        });
    }
    let mut terms = Vec::with_capacity(file.term.len());
    for (i, mut table) in file.term.into_iter().enumerate() {
        let kind = take_string(&mut table, i, "kind")?;
        let name = take_string(&mut table, i, "name")?;
        terms.push(registry.build(&kind, &name, table)?);
    }
    StageModel::new(file.description, terms, file.stochastic, file.environment)
}

pub(crate) fn render(model: &StageModel) -> Result<String, ModelError> {
    let mut term = Vec::with_capacity(model.terms().len());
    for t in model.terms() {
        let mut table = toml::Table::new();
        table.insert("kind".into(), toml::Value::String(t.kind().to_string()));
        table.insert("name".into(), toml::Value::String(t.name().to_string()));
        for (k, v) in t.to_config()? {
            table.insert(k, v);
        }
        term.push(table);
    }
    let file = ModelFile {
        format_version: FORMAT_VERSION,
        description: model.description().to_string(),
        stochastic: model.stochastic().clone(),
        environment: model.environment().clone(),
        term,
    };
    toml::to_string(&file).map_err(|e| ModelError::Serialize {
        what: "stage model".into(),
        message: e.to_string(),
    })
}

impl StageModel {
    /// The documented default (`config/stage-model.toml`), reproducing the
    /// paper's magnitudes.
    pub fn paper_default() -> Result<Self, ModelError> {
        Self::from_toml(PAPER_DEFAULT_TOML)
    }

    /// Loads a model file with the built-in terms.
    pub fn from_toml(text: &str) -> Result<Self, ModelError> {
        parse(text, &TermRegistry::builtin())
    }

    /// Loads a model file with extra registered terms.
    pub fn from_toml_with(text: &str, registry: &TermRegistry) -> Result<Self, ModelError> {
        parse(text, registry)
    }

    /// Writes the model file (every key, no comments). `from_toml(to_toml())`
    /// gives back the same model.
    pub fn to_toml(&self) -> Result<String, ModelError> {
        render(self)
    }
}
