//! Typed readings of controller answers.
//!
//! Why strict: a position that parses "mostly" is worse than an error. Every
//! function here either returns exactly what the answer says or an
//! [`AnswerError`] naming the line that did not fit.

use super::command::AxisId;
use super::frame::Answer;
use thiserror::Error;

/// Why an answer does not say what the command asked for.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AnswerError {
    /// The answer had no lines (or an empty line where a value was due).
    #[error("empty answer")]
    Empty,
    /// A line does not have the `key=value` form.
    #[error("line {0:?} is not of the form <axis>=<value>")]
    NotKeyValue(String),
    /// A value is not the number it should be.
    #[error("value {0:?} is not a number")]
    NotNumber(String),
    /// A value is not 0 or 1.
    #[error("value {0:?} is not a boolean (0 or 1)")]
    NotBool(String),
    /// A hex word is malformed.
    #[error("{0:?} is not a hexadecimal number")]
    NotHex(String),
    /// The `#7` answer is neither 0xB1 nor 0xB0.
    #[error("ready answer {0:02X?} is neither 0xB1 nor 0xB0")]
    NotReadyByte(Vec<u8>),
    /// The answer lacks an axis that was asked for.
    #[error("answer has no value for axis {0}")]
    MissingAxis(String),
    /// `*IDN?` does not have at least the vendor and model fields.
    #[error("identification {0:?} does not have 2 to 4 comma-separated fields (vendor, model, serial, firmware)")]
    BadIdn(String),
}

fn single_line(a: &Answer) -> Result<String, AnswerError> {
    let lines = a.lines();
    match lines.as_slice() {
        [l] if !l.trim().is_empty() => Ok(l.trim().to_owned()),
        _ => Err(AnswerError::Empty),
    }
}

/// Reads `axis=value` lines (POS?, ONT?, TMN?, ...), in answer order.
pub fn axis_values(a: &Answer) -> Result<Vec<(AxisId, String)>, AnswerError> {
    let lines = a.lines();
    if lines.is_empty() {
        return Err(AnswerError::Empty);
    }
    lines
        .iter()
        .map(|l| {
            let (k, v) = l
                .split_once('=')
                .ok_or_else(|| AnswerError::NotKeyValue(l.clone()))?;
            let axis = AxisId::new(k.trim()).map_err(|_| AnswerError::NotKeyValue(l.clone()))?;
            Ok((axis, v.trim().to_owned()))
        })
        .collect()
}

/// Parses a finite decimal number as PI formats them.
pub fn number(s: &str) -> Result<f64, AnswerError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(AnswerError::NotNumber(s.to_owned())),
    }
}

/// Parses a GCS boolean (`0`/`1`).
pub fn boolean(s: &str) -> Result<bool, AnswerError> {
    match s.trim() {
        "0" => Ok(false),
        "1" => Ok(true),
        other => Err(AnswerError::NotBool(other.to_owned())),
    }
}

/// The value for one axis, parsed with `f`.
pub fn value_for<T>(
    a: &Answer,
    axis: &AxisId,
    f: impl Fn(&str) -> Result<T, AnswerError>,
) -> Result<T, AnswerError> {
    let values = axis_values(a)?;
    let (_, v) = values
        .iter()
        .find(|(k, _)| k == axis)
        .ok_or_else(|| AnswerError::MissingAxis(axis.to_string()))?;
    f(v)
}

/// Parses `0x9005` (or a bare decimal) as an unsigned word; used by `#4`,
/// `#5` and `SRG?`.
pub fn hex_word(a: &Answer) -> Result<u32, AnswerError> {
    let s = single_line(a)?;
    let r = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => u32::from_str_radix(&s, 16),
    };
    r.map_err(|_| AnswerError::NotHex(s))
}

/// Reads the `#7` answer: true when ready (0xB1), false when busy (0xB0).
pub fn ready(a: &Answer) -> Result<bool, AnswerError> {
    match a.raw_lines() {
        [l] if l.as_slice() == [0xB1] => Ok(true),
        [l] if l.as_slice() == [0xB0] => Ok(false),
        other => Err(AnswerError::NotReadyByte(other.concat())),
    }
}

/// Reads `ERR?`.
pub fn error_code(a: &Answer) -> Result<super::GcsErrorCode, AnswerError> {
    let s = single_line(a)?;
    s.parse::<i32>()
        .map(super::GcsErrorCode)
        .map_err(|_| AnswerError::NotNumber(s))
}

/// What `*IDN?` says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identification {
    /// Manufacturer text, e.g. "(c)2015 Physik Instrumente (PI) GmbH & Co. KG".
    pub vendor: String,
    /// Model, e.g. "C-863.11".
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Firmware version.
    pub firmware: String,
}

impl Identification {
    /// Whether the model is a Mercury C-863 (the only controller micropos
    /// drives; others speak GCS too but differ in details that matter).
    pub fn is_c863(&self) -> bool {
        self.model.starts_with("C-863")
    }
}

/// Reads `*IDN?`: `vendor, model, serial, firmware`, or the older two-
/// or three-field form (`vendor, model Version x.y`, e.g. E-861 firmware),
/// whose model is the second field's first word (what PI's own client
/// reads) and the rest of it the firmware. Why accept it: identifying a PI
/// controller is the console's business for any model; whether micropos
/// may drive it is decided apart ([`Identification::is_c863`]).
pub fn identification(a: &Answer) -> Result<Identification, AnswerError> {
    let s = single_line(a)?;
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let own = |v: &str| v.to_owned();
    match parts.as_slice() {
        [vendor, model, serial, firmware] if !model.is_empty() => Ok(Identification {
            vendor: own(vendor),
            model: own(model),
            serial: own(serial),
            firmware: own(firmware),
        }),
        [vendor, second, rest @ ..] if rest.len() <= 1 && !second.is_empty() => {
            let (model, firmware) = second
                .split_once(char::is_whitespace)
                .map_or((*second, ""), |(m, f)| (m, f.trim()));
            Ok(Identification {
                vendor: own(vendor),
                model: own(model),
                serial: rest.first().map_or_else(String::new, |v| own(v)),
                firmware: own(firmware),
            })
        }
        _ => Err(AnswerError::BadIdn(s)),
    }
}

/// Reads a single-value answer as a number (`CSV?` → 2.0).
pub fn single_number(a: &Answer) -> Result<f64, AnswerError> {
    number(&single_line(a)?)
}

/// Reads a list of single-word lines (`SAI?` → `["1"]`).
pub fn word_list(a: &Answer) -> Result<Vec<String>, AnswerError> {
    let lines: Vec<String> = a.lines().into_iter().map(|l| l.trim().to_owned()).collect();
    if lines.is_empty() || lines.iter().any(String::is_empty) {
        return Err(AnswerError::Empty);
    }
    Ok(lines)
}

/// Reads `SPA?` lines `axis param=value` into (axis, param id, value text).
pub fn parameters(a: &Answer) -> Result<Vec<(AxisId, u32, String)>, AnswerError> {
    a.lines()
        .iter()
        .map(|l| {
            let bad = || AnswerError::NotKeyValue(l.clone());
            let (k, v) = l.split_once('=').ok_or_else(bad)?;
            let (axis, id) = k.trim().split_once(' ').ok_or_else(bad)?;
            let axis = AxisId::new(axis).map_err(|_| bad())?;
            let id = super::command::parse_param_id("SPA?", id.trim()).map_err(|_| bad())?;
            Ok((axis, id, v.trim().to_owned()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ans(lines: &[&str]) -> Answer {
        Answer::from_lines(lines.iter().map(|l| l.as_bytes().to_vec()).collect())
    }

    #[test]
    fn identification_in_four_and_in_two_fields() {
        let four = identification(&ans(&[
            "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0123456789, 01.110",
        ]))
        .unwrap();
        assert_eq!(
            (four.model.as_str(), four.serial.as_str(), four.is_c863()),
            ("C-863.11", "0123456789", true)
        );
        let two = identification(&ans(&[
            "(c)2013 Physik Instrumente(PI) Karlsruhe, E-861 Version 7.2.0",
        ]))
        .unwrap();
        assert_eq!(
            (
                two.model.as_str(),
                two.firmware.as_str(),
                two.serial.as_str()
            ),
            ("E-861", "Version 7.2.0", "")
        );
        assert!(!two.is_c863());
        for bad in ["just one field", "vendor,", "a, b, c, d, e"] {
            assert!(identification(&ans(&[bad])).is_err(), "{bad}");
        }
    }

    #[test]
    fn typed_readings() {
        let one = AxisId::new("1").unwrap();
        assert_eq!(
            value_for(&ans(&["1=12.3450000"]), &one, number).unwrap(),
            12.345
        );
        assert!(value_for(&ans(&["1=1"]), &one, boolean).unwrap());
        assert!(matches!(
            value_for(&ans(&["2=1"]), &one, boolean),
            Err(AnswerError::MissingAxis(_))
        ));
        assert!(matches!(
            value_for(&ans(&["1=nan"]), &one, number),
            Err(AnswerError::NotNumber(_))
        ));
        assert!(matches!(
            axis_values(&ans(&["garbage"])),
            Err(AnswerError::NotKeyValue(_))
        ));
        assert_eq!(hex_word(&ans(&["0x9005"])).unwrap(), 0x9005);
        assert_eq!(hex_word(&ans(&["1"])).unwrap(), 1);
        assert!(hex_word(&ans(&["0xZZ"])).is_err());
        assert!(ready(&Answer::from_lines(vec![vec![0xB1]])).unwrap());
        assert!(!ready(&Answer::from_lines(vec![vec![0xB0]])).unwrap());
        assert!(ready(&ans(&["1"])).is_err());
        assert_eq!(error_code(&ans(&["7"])).unwrap().0, 7);
        assert!(error_code(&ans(&[])).is_err());
        let idn = identification(&ans(&[
            "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0115500123, 01.110",
        ]))
        .unwrap();
        assert_eq!(idn.model, "C-863.11");
        assert!(idn.is_c863());
        assert!(identification(&ans(&["Arduino"])).is_err());
        assert_eq!(single_number(&ans(&["2.0"])).unwrap(), 2.0);
        assert_eq!(word_list(&ans(&["1", "2"])).unwrap(), vec!["1", "2"]);
        let p = parameters(&ans(&["1 0x3C=M-111.1DG", "1 0x15=15.000000"])).unwrap();
        assert_eq!(p[0], (one.clone(), 0x3C, "M-111.1DG".to_owned()));
        assert!(parameters(&ans(&["1=3"])).is_err());
    }
}
