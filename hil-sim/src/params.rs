//! The C-863 parameters the simulator knows (`SPA`, `SPA?`, `HPA?`).
//!
//! Why a table: `VEL`, `ACC`, `DEC`, `TMN?`, `TMX?` and `CST?` are, on a
//! C-863, views of parameters in RAM. Keeping them in one table means `SPA`
//! and the dedicated commands can never disagree, and `HPA?` lists exactly
//! what `SPA?` accepts. Ids and meanings follow PI's C-863 parameter list;
//! the default values describe an M-111.1DG stage (15 mm travel, reference
//! switch at mid travel, 1.5 mm/s maximum velocity).

use std::collections::BTreeMap;

/// Parameter id: P-term of the servo loop.
pub const P_TERM: u32 = 0x1;
/// Parameter id: I-term of the servo loop.
pub const I_TERM: u32 = 0x2;
/// Parameter id: D-term of the servo loop.
pub const D_TERM: u32 = 0x3;
/// Parameter id: I-limit of the servo loop.
pub const I_LIMIT: u32 = 0x4;
/// Parameter id: maximum position error (mm) before the servo trips.
pub const MAX_POSITION_ERROR: u32 = 0x8;
/// Parameter id: maximum closed-loop velocity (mm/s); the ceiling for `VEL`.
pub const MAX_VELOCITY: u32 = 0xA;
/// Parameter id: closed-loop acceleration (mm/s²); what `ACC` sets.
pub const ACCELERATION: u32 = 0xB;
/// Parameter id: closed-loop deceleration (mm/s²); what `DEC` sets.
pub const DECELERATION: u32 = 0xC;
/// Parameter id: numerator of the encoder counts per mm.
pub const COUNTS_PER_UNIT_NUM: u32 = 0xE;
/// Parameter id: denominator of the encoder counts per mm.
pub const COUNTS_PER_UNIT_DEN: u32 = 0xF;
/// Parameter id: whether the stage has a reference switch (1) or not (0).
pub const HAS_REFERENCE: u32 = 0x14;
/// Parameter id: maximum travel in positive direction (mm); `TMX?`.
pub const MAX_TRAVEL_POS: u32 = 0x15;
/// Parameter id: position value assigned at the reference switch (mm).
pub const VALUE_AT_REFERENCE: u32 = 0x16;
/// Parameter id: distance from the negative limit to the reference (mm).
pub const DIST_NEG_LIMIT_TO_REF: u32 = 0x17;
/// Parameter id: distance from the reference to the positive limit (mm).
pub const DIST_REF_TO_POS_LIMIT: u32 = 0x2F;
/// Parameter id: maximum travel in negative direction (mm); `TMN?` (the
/// simulator reports it as the lower soft limit itself, see docs/design/sim-controllers.md).
pub const MAX_TRAVEL_NEG: u32 = 0x30;
/// Parameter id: stage name; `CST?`.
pub const STAGE_NAME: u32 = 0x3C;
/// Parameter id: closed-loop velocity (mm/s); what `VEL` sets.
pub const VELOCITY: u32 = 0x49;
/// Parameter id: maximum closed-loop acceleration (mm/s²); ceiling for `ACC`.
pub const MAX_ACCELERATION: u32 = 0x4A;
/// Parameter id: maximum closed-loop deceleration (mm/s²); ceiling for `DEC`.
pub const MAX_DECELERATION: u32 = 0x4B;
/// Parameter id: velocity of referencing moves (mm/s).
pub const REFERENCE_VELOCITY: u32 = 0x50;

/// The data type of a parameter, as `HPA?` names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamType {
    /// Integer.
    Int,
    /// Floating point.
    Float,
    /// Text (no spaces: GCS splits arguments at spaces).
    Char,
}

impl ParamType {
    fn name(self) -> &'static str {
        match self {
            Self::Int => "INT",
            Self::Float => "FLOAT",
            Self::Char => "CHAR",
        }
    }
}

/// A parameter value.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// An integer parameter.
    Int(i64),
    /// A floating-point parameter.
    Float(f64),
    /// A text parameter.
    Text(String),
}

impl ParamValue {
    /// The value as a number (text parameters have none).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Self::Int(i) => Some(*i as f64),
            Self::Float(f) => Some(*f),
            Self::Text(_) => None,
        }
    }

    /// The value as `SPA?` prints it.
    pub fn to_text(&self) -> String {
        match self {
            Self::Int(i) => i.to_string(),
            Self::Float(f) => format!("{f:.6}"),
            Self::Text(t) => t.clone(),
        }
    }
}

/// One entry of the parameter table.
#[derive(Debug, Clone, Copy)]
pub struct ParamDef {
    /// The id (`0x3C`).
    pub id: u32,
    /// The data type.
    pub kind: ParamType,
    /// Default value text (parsed with [`parse_value`]).
    pub default: &'static str,
    /// Function group, as `HPA?` lists it.
    pub group: &'static str,
    /// What it means.
    pub description: &'static str,
    /// Whether the value must be a positive number (velocities,
    /// accelerations, the counts-per-unit factors).
    pub positive: bool,
}

const fn def(
    id: u32,
    kind: ParamType,
    default: &'static str,
    group: &'static str,
    description: &'static str,
    positive: bool,
) -> ParamDef {
    ParamDef {
        id,
        kind,
        default,
        group,
        description,
        positive,
    }
}

use ParamType::{Char, Float, Int};

/// Every parameter the simulated C-863 knows, in id order.
pub const PARAMS: &[ParamDef] = &[
    def(P_TERM, Int, "150", "motorcontroller", "P-Term", false),
    def(I_TERM, Int, "60", "motorcontroller", "I-Term", false),
    def(D_TERM, Int, "400", "motorcontroller", "D-Term", false),
    def(I_LIMIT, Int, "2000", "motorcontroller", "I-Limit", false),
    def(
        MAX_POSITION_ERROR,
        Float,
        "1.0",
        "motorcontroller",
        "Maximum_Position_Error_(Phys._Unit)",
        true,
    ),
    def(
        MAX_VELOCITY,
        Float,
        "1.5",
        "motorcontroller",
        "Maximum_Closed-Loop_Velocity_(Phys._Unit/s)",
        true,
    ),
    def(
        ACCELERATION,
        Float,
        "10.0",
        "motorcontroller",
        "Closed-Loop_Acceleration_(Phys._Unit/s2)",
        true,
    ),
    def(
        DECELERATION,
        Float,
        "10.0",
        "motorcontroller",
        "Closed-Loop_Deceleration_(Phys._Unit/s2)",
        true,
    ),
    def(
        COUNTS_PER_UNIT_NUM,
        Int,
        "145000",
        "stage",
        "Numerator_Of_The_Counts-Per-Physical-Unit_Factor",
        true,
    ),
    def(
        COUNTS_PER_UNIT_DEN,
        Int,
        "1",
        "stage",
        "Denominator_Of_The_Counts-Per-Physical-Unit_Factor",
        true,
    ),
    def(
        HAS_REFERENCE,
        Int,
        "1",
        "stage",
        "Stage_Has_Reference",
        false,
    ),
    def(
        MAX_TRAVEL_POS,
        Float,
        "15.0",
        "stage",
        "Maximum_Travel_In_Positive_Direction_(Phys._Unit)",
        false,
    ),
    def(
        VALUE_AT_REFERENCE,
        Float,
        "7.5",
        "stage",
        "Value_At_Reference_Position_(Phys._Unit)",
        false,
    ),
    def(
        DIST_NEG_LIMIT_TO_REF,
        Float,
        "7.5",
        "stage",
        "Distance_From_Negative_Limit_To_Reference_Position_(Phys._Unit)",
        false,
    ),
    def(
        DIST_REF_TO_POS_LIMIT,
        Float,
        "7.5",
        "stage",
        "Distance_From_Reference_Position_To_Positive_Limit_(Phys._Unit)",
        false,
    ),
    def(
        MAX_TRAVEL_NEG,
        Float,
        "0.0",
        "stage",
        "Maximum_Travel_In_Negative_Direction_(Phys._Unit)",
        false,
    ),
    def(STAGE_NAME, Char, "M-111.1DG", "stage", "Stage_Name", false),
    def(
        VELOCITY,
        Float,
        "1.0",
        "motorcontroller",
        "Closed-Loop_Velocity_(Phys._Unit/s)",
        true,
    ),
    def(
        MAX_ACCELERATION,
        Float,
        "20.0",
        "motorcontroller",
        "Maximum_Closed-Loop_Acceleration_(Phys._Unit/s2)",
        true,
    ),
    def(
        MAX_DECELERATION,
        Float,
        "20.0",
        "motorcontroller",
        "Maximum_Closed-Loop_Deceleration_(Phys._Unit/s2)",
        true,
    ),
    def(
        REFERENCE_VELOCITY,
        Float,
        "0.5",
        "motorcontroller",
        "Velocity_For_Reference_Moves_(Phys._Unit/s)",
        true,
    ),
];

/// The table entry for an id.
pub fn lookup(id: u32) -> Option<&'static ParamDef> {
    PARAMS.iter().find(|d| d.id == id)
}

/// Why a value cannot be stored in a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueError {
    /// Not a number of the parameter's type.
    Syntax,
    /// A number, but outside the allowed range.
    OutOfRange,
}

/// Parses a value for a parameter of this definition.
pub fn parse_value(d: &ParamDef, text: &str) -> Result<ParamValue, ValueError> {
    let v = match d.kind {
        Int => ParamValue::Int(text.parse::<i64>().map_err(|_| ValueError::Syntax)?),
        Float => match text.parse::<f64>() {
            Ok(f) if f.is_finite() => ParamValue::Float(f),
            _ => return Err(ValueError::Syntax),
        },
        Char => {
            if text.is_empty() || text.len() > 64 || !text.bytes().all(|b| b.is_ascii_graphic()) {
                return Err(ValueError::Syntax);
            }
            ParamValue::Text(text.to_owned())
        }
    };
    if d.positive && v.as_f64().is_some_and(|f| f <= 0.0) {
        return Err(ValueError::OutOfRange);
    }
    Ok(v)
}

/// The parameter set of one axis, in RAM.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSet {
    values: BTreeMap<u32, ParamValue>,
}

impl Default for ParamSet {
    fn default() -> Self {
        let values = PARAMS
            .iter()
            .filter_map(|d| parse_value(d, d.default).ok().map(|v| (d.id, v)))
            .collect();
        Self { values }
    }
}

impl ParamSet {
    /// The value of a known parameter.
    pub fn get(&self, id: u32) -> Option<&ParamValue> {
        self.values.get(&id)
    }

    /// A numeric parameter, or `fallback` if it is unknown or text (never
    /// happens for the table above; the fallback keeps this panic-free).
    pub fn number(&self, id: u32, fallback: f64) -> f64 {
        self.get(id)
            .and_then(ParamValue::as_f64)
            .unwrap_or(fallback)
    }

    /// Stores a value (already validated with [`parse_value`]).
    pub fn set(&mut self, id: u32, v: ParamValue) {
        self.values.insert(id, v);
    }

    /// All (id, value) pairs in id order.
    pub fn iter(&self) -> impl Iterator<Item = (u32, &ParamValue)> {
        self.values.iter().map(|(k, v)| (*k, v))
    }
}

/// The `HPA?` lines: a header, one line per parameter, a trailer. The
/// parameter lines have PI's tab-separated layout
/// `0x1=<TAB>level<TAB>items<TAB>type<TAB>group<TAB>description`, which is
/// what PIPython parses to learn each parameter's type.
pub fn hpa_lines() -> Vec<String> {
    let mut out = vec!["The following parameters are valid:".to_owned()];
    for d in PARAMS {
        out.push(format!(
            "0x{:X}=\t0\t1\t{}\t{}\t{}",
            d.id,
            d.kind.name(),
            d.group,
            d.description
        ));
    }
    out.push("end of help".to_owned());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_parse_and_ids_are_unique() {
        let set = ParamSet::default();
        assert_eq!(set.iter().count(), PARAMS.len());
        let mut ids: Vec<u32> = PARAMS.iter().map(|d| d.id).collect();
        ids.dedup();
        assert_eq!(ids.len(), PARAMS.len(), "ids sorted and unique");
        assert!(ids.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(set.number(MAX_TRAVEL_POS, 0.0), 15.0);
        assert_eq!(
            set.get(STAGE_NAME),
            Some(&ParamValue::Text("M-111.1DG".into()))
        );
    }

    #[test]
    fn value_parsing() {
        let vel = lookup(VELOCITY).unwrap();
        assert_eq!(parse_value(vel, "1.25"), Ok(ParamValue::Float(1.25)));
        assert_eq!(parse_value(vel, "0"), Err(ValueError::OutOfRange));
        assert_eq!(parse_value(vel, "fast"), Err(ValueError::Syntax));
        assert_eq!(parse_value(vel, "inf"), Err(ValueError::Syntax));
        let p = lookup(P_TERM).unwrap();
        assert_eq!(parse_value(p, "12"), Ok(ParamValue::Int(12)));
        assert_eq!(parse_value(p, "1.5"), Err(ValueError::Syntax));
        let name = lookup(STAGE_NAME).unwrap();
        assert_eq!(
            parse_value(name, "NOSTAGE"),
            Ok(ParamValue::Text("NOSTAGE".into()))
        );
        assert!(lookup(0x999).is_none());
    }

    #[test]
    fn hpa_layout_matches_pipython_expectations() {
        let lines = hpa_lines();
        assert!(!lines[0].contains('='));
        assert!(!lines.last().unwrap().contains('='));
        for l in &lines[1..lines.len() - 1] {
            let fields: Vec<&str> = l.split_whitespace().collect();
            assert!(fields[0].ends_with('='));
            assert!(["INT", "FLOAT", "CHAR"].contains(&fields[3]), "{l}");
        }
    }
}
