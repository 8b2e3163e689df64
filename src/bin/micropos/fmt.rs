//! Numbers for a person: each quantity rounded to what it resolves, with
//! its unit. `--json` keeps full precision; text output never shows
//! `0.1720000000000255`-style noise (issue 33).
//!
//! The resolutions: positions to 0.001 µm (1 nm: below the decoder's and
//! the controllers' resolution, so nothing real is cut); spreads and rms
//! to three significant digits (their own uncertainty is larger than the
//! third digit); angles to 1 µrad; rig times to 1 ms, durations to three
//! significant digits.

use serde_json::Value;
use std::fmt::Write;

/// A position or distance, µm, to 0.001 µm: `16522.654 µm`.
pub fn um(v: f64) -> String {
    format!("{v:.3} µm")
}

/// A spread or rms, µm, to three significant digits: `0.570 µm`.
pub fn rms_um(v: f64) -> String {
    format!("{} µm", sig(v, 3))
}

/// `v` to `digits` significant digits, in plain notation (no exponent;
/// a large value keeps all its integer digits).
pub fn sig(v: f64, digits: i32) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".to_owned();
    }
    let magnitude = v.abs().log10().floor() as i32;
    let decimals = (digits - 1 - magnitude).clamp(0, 12) as usize;
    format!("{v:.decimals$}")
}

/// A code margin (the decoder's `quality`, bits) with what it means: how
/// much likelier the best code position is than the next best, against
/// the refusal threshold and the margin where a misread is practically
/// excluded.
pub fn margin_words(bits: f64) -> String {
    let verdict = if bits >= MARGIN_SAFE_BITS {
        "safe"
    } else if bits >= MARGIN_REFUSED_BITS {
        "thin: check focus, lighting and dust"
    } else {
        "below the refusal threshold: the decoder does not vouch for it"
    };
    format!(
        "code margin {bits:.0} bits (the best code position is 2^{bits:.0} times likelier than the next best; \
         refused below {MARGIN_REFUSED_BITS:.0}, safe from {MARGIN_SAFE_BITS:.0}: {verdict})"
    )
}

/// The short form of [`margin_words`]: `785 bits code margin (safe)`.
pub fn margin_short(bits: f64) -> String {
    let verdict = if bits >= MARGIN_SAFE_BITS {
        "safe"
    } else if bits >= MARGIN_REFUSED_BITS {
        "thin: check focus, lighting, dust"
    } else {
        "below the refusal threshold"
    };
    format!(
        "{bits:.0} bits of code margin ({verdict}; refused below {MARGIN_REFUSED_BITS:.0}, safe from {MARGIN_SAFE_BITS:.0})"
    )
}

/// Margin (bits of evidence) below which a decode is refused
/// (`CoarseThresholds::min_code_margin_bits`' default).
pub const MARGIN_REFUSED_BITS: f64 = 16.0;
/// Margin above which a misread code position is practically excluded
/// (a likelihood ratio of 2⁴⁰ ≈ 10¹², where clean views score hundreds).
pub const MARGIN_SAFE_BITS: f64 = 40.0;

/// How a value under a key is written: the key without its unit suffix,
/// and a formatter of the number with its unit.
struct Unit {
    /// The key's unit suffix (`_um`), stripped from the label.
    suffix: &'static str,
    /// The number, rounded, with the unit.
    show: fn(&str, f64) -> String,
}

/// The units keys end in (longest first: `_um_per_s` before `_s`).
const UNITS: &[Unit] = &[
    Unit {
        suffix: "_um_per_s",
        show: |_, v| format!("{v:.1} µm/s"),
    },
    Unit {
        suffix: "_urad",
        show: |_, v| format!("{v:.1} µrad"),
    },
    Unit {
        suffix: "_rad",
        show: |_, v| format!("{v:.6} rad"),
    },
    Unit {
        suffix: "_ppm",
        show: |_, v| format!("{v:.1} ppm"),
    },
    Unit {
        suffix: "_um",
        show: |key, v| {
            if ["rms", "spread", "sigma", "residual", "scatter"]
                .iter()
                .any(|w| key.contains(w))
            {
                rms_um(v)
            } else {
                um(v)
            }
        },
    },
    Unit {
        suffix: "_ms",
        show: |_, v| format!("{} ms", sig(v, 3)),
    },
    Unit {
        suffix: "_s",
        show: |key, v| seconds(key, v),
    },
    Unit {
        suffix: "_c",
        show: |_, v| format!("{v:.2} °C"),
    },
    Unit {
        suffix: "_hz",
        show: |_, v| format!("{} Hz", sig(v, 3)),
    },
    Unit {
        suffix: "_pct",
        show: |_, v| format!("{v:.1} %"),
    },
];

/// A time, s: a rig time stamp (`t_s`, `frame_t_s`) to 1 ms, a duration
/// to three significant digits (whole seconds from 1000 s on).
fn seconds(key: &str, v: f64) -> String {
    if key == "t_s" || key.ends_with("_t_s") {
        format!("{v:.3} s")
    } else {
        format!("{} s", sig(v, 3))
    }
}

/// The unit a key ends in. A rate other than µm/s (`rate_per_s`,
/// `um_per_c`) has none here: its last suffix is not its unit, so it keeps
/// its full key as the label.
fn unit_of(key: &str) -> Option<&'static Unit> {
    let unit = UNITS
        .iter()
        .find(|u| key.ends_with(u.suffix) && key.len() > u.suffix.len())?;
    (unit.suffix.contains("_per_") || !key.contains("_per_")).then_some(unit)
}

/// A number under `key` for a person: with the key's unit, rounded to
/// its resolution; the decoder's `quality` as bits of code margin; a
/// whole number as it is; any other number to four significant digits.
pub fn number(key: &str, n: &serde_json::Number) -> String {
    let Some(v) = n.as_f64() else {
        return n.to_string();
    };
    if let Some(u) = unit_of(key) {
        return (u.show)(key, v);
    }
    if key == "quality" {
        return margin_short(v);
    }
    if n.is_f64() {
        // Without a unit there is no resolution to show: no trailing zeros.
        let s = sig(v, 4);
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_owned()
        } else {
            s
        }
    } else {
        n.to_string()
    }
}

/// The key as a label: without the unit suffix its value now carries
/// (`x_um` → `x`).
fn label(key: &str) -> &str {
    unit_of(key).map_or(key, |u| &key[..key.len() - u.suffix.len()])
}

/// A JSON reply as indented `key: value` lines, keys in the reply's
/// order, every number with its unit and rounded (see [`number`]), a list
/// of numbers on one line, a list of objects as items. `id` and `ok` are
/// left out.
///
/// A unit on an object's key (`rms_error_um: {"x": …, "y": …}`) applies
/// to its members.
pub fn human(v: &Value) -> String {
    let mut out = String::new();
    if let Value::Object(m) = v {
        for (k, x) in m {
            if k != "id" && k != "ok" {
                entry(k, None, x, 0, &mut out);
            }
        }
    }
    out
}

/// One `key: value` (and what is below it) at `indent`; `unit_key`: the
/// key a member inherits its unit from.
fn entry(k: &str, unit_key: Option<&str>, x: &Value, indent: usize, out: &mut String) {
    let own_unit = unit_of(k).is_some();
    let key = if own_unit { k } else { unit_key.unwrap_or(k) };
    let shown = label(k);
    match x {
        Value::Object(m) => {
            let _ = writeln!(out, "{:indent$}{shown}:", "");
            let inherit = if own_unit { Some(k) } else { unit_key };
            for (ck, cx) in m {
                entry(ck, inherit, cx, indent + 2, out);
            }
        }
        Value::Array(a) if a.iter().any(Value::is_object) => {
            let _ = writeln!(out, "{:indent$}{shown}:", "");
            for (i, item) in a.iter().enumerate() {
                match item {
                    Value::Object(m) => {
                        let _ = writeln!(out, "{:w$}- {}", "", i + 1, w = indent + 2);
                        for (ck, cx) in m {
                            entry(ck, None, cx, indent + 4, out);
                        }
                    }
                    other => {
                        let _ = writeln!(out, "{:w$}- {}", "", scalar(key, other), w = indent + 2);
                    }
                }
            }
        }
        Value::Array(a) if a.is_empty() => {
            let _ = writeln!(out, "{:indent$}{shown}: none", "");
        }
        Value::Array(a) => {
            let _ = writeln!(out, "{:indent$}{shown}: {}", "", list(key, a));
        }
        other => {
            let _ = writeln!(out, "{:indent$}{shown}: {}", "", scalar(key, other));
        }
    }
}

/// A list of scalars on one line: numbers rounded with the unit once at
/// the end (`[0.000, 15000.000] µm`), strings comma-separated.
fn list(key: &str, a: &[Value]) -> String {
    if !a.iter().all(Value::is_number) {
        return a
            .iter()
            .map(|x| scalar(key, x))
            .collect::<Vec<_>>()
            .join(", ");
    }
    let shown: Vec<String> = a
        .iter()
        .filter_map(Value::as_number)
        .map(|n| number(key, n))
        .collect();
    // Each is "NUMBER UNIT" when the key has a unit: the unit once.
    let unit = unit_of(key).and_then(|_| {
        shown
            .first()
            .and_then(|s| s.split_once(' '))
            .map(|(_, u)| u.to_owned())
    });
    match unit {
        Some(u) => {
            let nums: Vec<&str> = shown
                .iter()
                .map(|s| s.split_once(' ').map_or(s.as_str(), |(n, _)| n))
                .collect();
            format!("[{}] {u}", nums.join(", "))
        }
        None => format!("[{}]", shown.join(", ")),
    }
}

/// A scalar under `key`: a number via [`number`], a string as it is,
/// null as `-`.
fn scalar(key: &str, x: &Value) -> String {
    match x {
        Value::Null => "-".to_owned(),
        Value::Number(n) => number(key, n),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn significant_digits_in_plain_notation() {
        assert_eq!(sig(0.5700706466147496, 3), "0.570");
        assert_eq!(sig(4.6007803683465065, 3), "4.60");
        assert_eq!(sig(784.8261022435961, 4), "784.8");
        assert_eq!(sig(12345.678, 3), "12346");
        assert_eq!(sig(-0.00123456, 2), "-0.0012");
        assert_eq!(sig(0.0, 3), "0");
    }

    /// Issue 33's raw numbers: every number of a reply rounded, with its
    /// unit, nothing of the float noise left.
    #[test]
    fn replies_print_rounded_numbers_with_units() {
        let v = json!({"id": 1, "ok": true,
            "model": {"rms_residual_um": [0.5700706466147496, 0.7096313158065792]},
            "report": {"y_reference_um": [-0.1720000000000255, 0.512449999999717],
                       "squareness_urad": 5623.586812, "x_points": [11, 10]},
            "target": {"x_um": 16522.654282786934},
            "limits": {"x_um": [0.0, 15000.0]},
            "rms_error_um": {"x": 4.6007803683465065, "y": 0.19937879175275167},
            "latest": {"t_s": 2287.425264875, "theta_rad": 0.005241216334754882,
                       "quality": 784.8261022435961},
            "poses": [{"pose": "A", "ap_um": 4.123456}],
            "ratio": 0.123456789, "count": 7, "none": null, "names": ["a", "b"],
            "rate_per_s": 5.0, "x_um_per_c": 0.123456, "velocity_um_per_s": 120.04});
        let t = human(&v);
        for want in [
            "model:\n  rms_residual: [0.570, 0.710] µm\n",
            "  y_reference: [-0.172, 0.512] µm\n",
            "  squareness: 5623.6 µrad\n",
            "  x_points: [11, 10]\n",
            "target:\n  x: 16522.654 µm\n",
            "limits:\n  x: [0.000, 15000.000] µm\n",
            "rms_error:\n  x: 4.60 µm\n  y: 0.199 µm\n",
            "  t: 2287.425 s\n",
            "  theta: 0.005241 rad\n",
            "  quality: 785 bits of code margin (safe;",
            "poses:\n  - 1\n    ap: 4.123 µm\n    pose: A\n",
            "ratio: 0.1235\n",
            "count: 7\n",
            "none: -\n",
            "names: a, b\n",
            "rate_per_s: 5\n",
            "x_um_per_c: 0.1235\n",
            "velocity: 120.0 µm/s\n",
        ] {
            assert!(t.contains(want), "want {want:?} in\n{t}");
        }
        assert!(!t.contains("000000"), "{t}");
        assert!(!t.contains("id:") && !t.contains("ok:"), "{t}");
    }
}
