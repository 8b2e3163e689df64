//! Typed GCS 2.0 commands (host → controller) and their text form.
//!
//! The same type serves both ends: the driver formats commands with
//! [`Command::to_text`], the simulator parses received lines with
//! [`Command::parse`]. Keeping both in one place is what guarantees that the
//! simulator accepts exactly what the driver sends.

use std::fmt;
use thiserror::Error;

/// An axis identifier. On a C-863 it is `1` unless renamed with `SAI`;
/// GCS allows up to 8 characters of `[0-9A-Za-z_]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct AxisId(String);

impl AxisId {
    /// Validates an identifier.
    pub fn new(s: &str) -> Result<Self, CommandError> {
        if !s.is_empty()
            && s.len() <= 8
            && s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
        {
            Ok(Self(s.to_owned()))
        } else {
            Err(CommandError::BadAxis(s.to_owned()))
        }
    }

    /// The identifier text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for AxisId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// Why a command line could not be parsed or built. A controller answers all
/// of these with silence and an error code; [`CommandError::gcs_code`] says
/// which.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CommandError {
    /// The mnemonic is not a command micropos (or the simulated C-863) knows.
    #[error("unknown command {0:?}")]
    Unknown(String),
    /// Wrong number of arguments for the command.
    #[error("{cmd}: wrong number of arguments")]
    ArgCount {
        /// The mnemonic.
        cmd: &'static str,
    },
    /// An argument that should be a number is not.
    #[error("{cmd}: {arg:?} is not a number")]
    BadNumber {
        /// The mnemonic.
        cmd: &'static str,
        /// The offending argument.
        arg: String,
    },
    /// An axis identifier with forbidden characters.
    #[error("invalid axis identifier {0:?}")]
    BadAxis(String),
}

impl CommandError {
    /// The GCS error a controller sets for this problem.
    pub fn gcs_code(&self) -> super::GcsErrorCode {
        use super::GcsErrorCode as E;
        match self {
            Self::Unknown(_) => E::UNKNOWN_COMMAND,
            Self::ArgCount { .. } => E::WRONG_PARAM_COUNT,
            Self::BadNumber { .. } => E::PARAM_SYNTAX,
            Self::BadAxis(_) => E::INVALID_AXIS,
        }
    }
}

/// Which axes a query or a command names; empty means "all axes".
pub type Axes = Vec<AxisId>;

/// A GCS 2.0 command line, as far as micropos and the simulated C-863 use
/// them. Positions and velocities are in the controller's units (mm, mm/s).
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// `*IDN?`: identification string.
    Idn,
    /// `CSV?`: GCS syntax version (2.0 on a C-863).
    Csv,
    /// `ERR?`: last error code, cleared by reading it.
    Err,
    /// `HLP?`: list of commands.
    Hlp,
    /// `HPA?`: list of parameters.
    Hpa,
    /// `VER?`: firmware versions.
    Ver,
    /// `SAI?` (false) or `SAI? ALL` (true): axis identifiers.
    SaiQuery {
        /// Include deactivated axes.
        all: bool,
    },
    /// `CST?`: stage names.
    CstQuery(Axes),
    /// `TMN?`: lower soft limit (mm).
    TmnQuery(Axes),
    /// `TMX?`: upper soft limit (mm).
    TmxQuery(Axes),
    /// `POS?`: current position (mm).
    PosQuery(Axes),
    /// `MOV?`: commanded target (mm).
    MovQuery(Axes),
    /// `ONT?`: on-target state.
    OntQuery(Axes),
    /// `FRF?`: referenced state.
    FrfQuery(Axes),
    /// `SVO?`: servo state.
    SvoQuery(Axes),
    /// `VEL?`: velocity (mm/s).
    VelQuery(Axes),
    /// `ACC?`: acceleration (mm/s²).
    AccQuery(Axes),
    /// `DEC?`: deceleration (mm/s²).
    DecQuery(Axes),
    /// `RON?`: reference mode.
    RonQuery(Axes),
    /// `SPA?`: parameter values; empty means all of them.
    SpaQuery(Vec<(AxisId, u32)>),
    /// `SVO axis 0|1`: servo off/on.
    Svo(Vec<(AxisId, bool)>),
    /// `RON axis 0|1`: reference mode on/off.
    Ron(Vec<(AxisId, bool)>),
    /// `FRF [axes]`: reference to the reference switch.
    Frf(Axes),
    /// `FNL [axes]`: reference to the negative limit switch.
    Fnl(Axes),
    /// `FPL [axes]`: reference to the positive limit switch.
    Fpl(Axes),
    /// `MOV axis pos ...`: absolute move (mm).
    Mov(Vec<(AxisId, f64)>),
    /// `MVR axis dist ...`: relative move (mm).
    Mvr(Vec<(AxisId, f64)>),
    /// `VEL axis v ...`: velocity (mm/s).
    Vel(Vec<(AxisId, f64)>),
    /// `ACC axis a ...`: acceleration (mm/s²).
    Acc(Vec<(AxisId, f64)>),
    /// `DEC axis a ...`: deceleration (mm/s²).
    Dec(Vec<(AxisId, f64)>),
    /// `SPA axis param value ...`: set parameters (value kept as text: PI
    /// parameters are numbers or strings).
    Spa(Vec<(AxisId, u32, String)>),
    /// `HLT [axes]`: smooth halt (sets error 10).
    Hlt(Axes),
    /// `STP`: stop all at once (sets error 10).
    Stp,
    /// `TNR?`: number of data recorder tables (`gcs::recorder`).
    TnrQuery,
    /// `HDR?`: the data recorder's record options and trigger sources.
    HdrQuery,
    /// `DRC table source option ...`: what a record table records.
    Drc(Vec<(u32, AxisId, u32)>),
    /// `DRC? [tables]`: record table configuration.
    DrcQuery(Vec<u32>),
    /// `RTR rate`: record table rate, servo cycles per record.
    Rtr(u32),
    /// `RTR?`: record table rate.
    RtrQuery,
    /// `DRT table source value ...`: trigger source of a record table
    /// (table 0: all tables).
    Drt(Vec<(u32, u32, String)>),
    /// `DRL? [tables]`: records taken since the last trigger.
    DrlQuery(Vec<u32>),
    /// `DRR? [start [count [tables]]]`: read records (GCS array data;
    /// `start` counts from 1).
    DrrQuery {
        /// First record, 1-based.
        start: Option<u32>,
        /// Records per table.
        count: Option<u32>,
        /// Tables; empty: all.
        tables: Vec<u32>,
    },
}

fn axes_text(name: &str, axes: &[AxisId]) -> String {
    let mut s = name.to_owned();
    for a in axes {
        s.push(' ');
        s.push_str(a.as_str());
    }
    s
}

/// Formats a number of mm for the controller: enough digits for 0.1 nm,
/// trailing zeros trimmed, never exponent notation.
pub fn format_number(v: f64) -> String {
    let s = format!("{v:.7}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_owned()
    } else {
        s.to_owned()
    }
}

fn pairs_text<T>(name: &str, pairs: &[(AxisId, T)], f: impl Fn(&T) -> String) -> String {
    let mut s = name.to_owned();
    for (a, v) in pairs {
        s.push(' ');
        s.push_str(a.as_str());
        s.push(' ');
        s.push_str(&f(v));
    }
    s
}

impl Command {
    /// The mnemonic (`"MOV"`, `"POS?"`, ...).
    pub fn mnemonic(&self) -> &'static str {
        match self {
            Self::Idn => "*IDN?",
            Self::Csv => "CSV?",
            Self::Err => "ERR?",
            Self::Hlp => "HLP?",
            Self::Hpa => "HPA?",
            Self::Ver => "VER?",
            Self::SaiQuery { .. } => "SAI?",
            Self::CstQuery(_) => "CST?",
            Self::TmnQuery(_) => "TMN?",
            Self::TmxQuery(_) => "TMX?",
            Self::PosQuery(_) => "POS?",
            Self::MovQuery(_) => "MOV?",
            Self::OntQuery(_) => "ONT?",
            Self::FrfQuery(_) => "FRF?",
            Self::SvoQuery(_) => "SVO?",
            Self::VelQuery(_) => "VEL?",
            Self::AccQuery(_) => "ACC?",
            Self::DecQuery(_) => "DEC?",
            Self::RonQuery(_) => "RON?",
            Self::SpaQuery(_) => "SPA?",
            Self::Svo(_) => "SVO",
            Self::Ron(_) => "RON",
            Self::Frf(_) => "FRF",
            Self::Fnl(_) => "FNL",
            Self::Fpl(_) => "FPL",
            Self::Mov(_) => "MOV",
            Self::Mvr(_) => "MVR",
            Self::Vel(_) => "VEL",
            Self::Acc(_) => "ACC",
            Self::Dec(_) => "DEC",
            Self::Spa(_) => "SPA",
            Self::Hlt(_) => "HLT",
            Self::Stp => "STP",
            Self::TnrQuery => "TNR?",
            Self::HdrQuery => "HDR?",
            Self::Drc(_) => "DRC",
            Self::DrcQuery(_) => "DRC?",
            Self::Rtr(_) => "RTR",
            Self::RtrQuery => "RTR?",
            Self::Drt(_) => "DRT",
            Self::DrlQuery(_) => "DRL?",
            Self::DrrQuery { .. } => "DRR?",
        }
    }

    /// Whether the controller answers it. Queries answer; set commands are
    /// silent and report problems only through `ERR?`.
    pub fn is_query(&self) -> bool {
        self.mnemonic().ends_with('?')
    }

    /// The command line as sent (without LF and address prefix).
    pub fn to_text(&self) -> String {
        let bool_text = |b: &bool| if *b { "1".to_owned() } else { "0".to_owned() };
        match self {
            Self::Idn
            | Self::Csv
            | Self::Err
            | Self::Hlp
            | Self::Hpa
            | Self::Ver
            | Self::Stp
            | Self::TnrQuery
            | Self::HdrQuery
            | Self::RtrQuery => self.mnemonic().to_owned(),
            Self::Rtr(r) => format!("RTR {r}"),
            Self::Drc(items) => {
                let mut s = "DRC".to_owned();
                for (t, src, opt) in items {
                    s.push_str(&format!(" {t} {src} {opt}"));
                }
                s
            }
            Self::Drt(items) => {
                let mut s = "DRT".to_owned();
                for (t, src, v) in items {
                    s.push_str(&format!(" {t} {src} {v}"));
                }
                s
            }
            Self::DrcQuery(t) | Self::DrlQuery(t) => {
                let mut s = self.mnemonic().to_owned();
                for x in t {
                    s.push_str(&format!(" {x}"));
                }
                s
            }
            Self::DrrQuery {
                start,
                count,
                tables,
            } => {
                let mut s = "DRR?".to_owned();
                if let Some(a) = start {
                    s.push_str(&format!(" {a}"));
                    if let Some(n) = count {
                        s.push_str(&format!(" {n}"));
                        for t in tables {
                            s.push_str(&format!(" {t}"));
                        }
                    }
                }
                s
            }
            Self::SaiQuery { all } => {
                if *all {
                    "SAI? ALL".to_owned()
                } else {
                    "SAI?".to_owned()
                }
            }
            Self::CstQuery(a)
            | Self::TmnQuery(a)
            | Self::TmxQuery(a)
            | Self::PosQuery(a)
            | Self::MovQuery(a)
            | Self::OntQuery(a)
            | Self::FrfQuery(a)
            | Self::SvoQuery(a)
            | Self::VelQuery(a)
            | Self::AccQuery(a)
            | Self::DecQuery(a)
            | Self::RonQuery(a)
            | Self::Frf(a)
            | Self::Fnl(a)
            | Self::Fpl(a)
            | Self::Hlt(a) => axes_text(self.mnemonic(), a),
            Self::SpaQuery(p) => pairs_text("SPA?", p, |id| format!("0x{id:X}")),
            Self::Svo(p) | Self::Ron(p) => pairs_text(self.mnemonic(), p, bool_text),
            Self::Mov(p) | Self::Mvr(p) | Self::Vel(p) | Self::Acc(p) | Self::Dec(p) => {
                pairs_text(self.mnemonic(), p, |v| format_number(*v))
            }
            Self::Spa(p) => {
                let mut s = "SPA".to_owned();
                for (a, id, v) in p {
                    s.push_str(&format!(" {a} 0x{id:X} {v}"));
                }
                s
            }
        }
    }

    /// Parses a received command line (address prefix already removed).
    ///
    /// Mnemonics are case-sensitive upper case, as on PI controllers;
    /// arguments are separated by one or more spaces. Each family of
    /// commands (no arguments, axes, axis-value pairs, tables and
    /// parameters) has its own reader; a mnemonic belongs to one only.
    pub fn parse(line: &str) -> Result<Self, CommandError> {
        let mut words = line.split(' ').filter(|w| !w.is_empty());
        let Some(mnemonic) = words.next() else {
            return Err(CommandError::Unknown(String::new()));
        };
        let args: Vec<&str> = words.collect();
        if let Some((cmd, c)) = Self::without_args(mnemonic) {
            return if args.is_empty() {
                Ok(c)
            } else {
                Err(CommandError::ArgCount { cmd })
            };
        }
        Self::on_axes(mnemonic, &args)
            .or_else(|| Self::axis_values(mnemonic, &args))
            .or_else(|| Self::tables_and_parameters(mnemonic, &args))
            .unwrap_or_else(|| Err(CommandError::Unknown(mnemonic.to_owned())))
    }

    /// The commands that take no argument, with their mnemonic.
    fn without_args(mnemonic: &str) -> Option<(&'static str, Self)> {
        Some(match mnemonic {
            "*IDN?" => ("*IDN?", Self::Idn),
            "CSV?" => ("CSV?", Self::Csv),
            "ERR?" => ("ERR?", Self::Err),
            "HLP?" => ("HLP?", Self::Hlp),
            "HPA?" => ("HPA?", Self::Hpa),
            "VER?" => ("VER?", Self::Ver),
            "STP" => ("STP", Self::Stp),
            "TNR?" => ("TNR?", Self::TnrQuery),
            "HDR?" => ("HDR?", Self::HdrQuery),
            "RTR?" => ("RTR?", Self::RtrQuery),
            _ => return None,
        })
    }

    /// The commands whose arguments are axes (none: every axis).
    fn on_axes(mnemonic: &str, args: &[&str]) -> Option<Result<Self, CommandError>> {
        let make: fn(Axes) -> Self = match mnemonic {
            "CST?" => Self::CstQuery,
            "TMN?" => Self::TmnQuery,
            "TMX?" => Self::TmxQuery,
            "POS?" => Self::PosQuery,
            "MOV?" => Self::MovQuery,
            "ONT?" => Self::OntQuery,
            "FRF?" => Self::FrfQuery,
            "SVO?" => Self::SvoQuery,
            "VEL?" => Self::VelQuery,
            "ACC?" => Self::AccQuery,
            "DEC?" => Self::DecQuery,
            "RON?" => Self::RonQuery,
            "FRF" => Self::Frf,
            "FNL" => Self::Fnl,
            "FPL" => Self::Fpl,
            "HLT" => Self::Hlt,
            _ => return None,
        };
        Some(
            args.iter()
                .map(|a| AxisId::new(a))
                .collect::<Result<_, _>>()
                .map(make),
        )
    }

    /// The commands whose arguments are axis-value pairs: numbers, or
    /// switches (`0`, `1`).
    fn axis_values(mnemonic: &str, args: &[&str]) -> Option<Result<Self, CommandError>> {
        let numbers = |cmd, make: fn(Vec<(AxisId, f64)>) -> Self| {
            groups::<2, _>(cmd, args, |c| {
                Ok((AxisId::new(c[0])?, parse_f64(cmd, c[1])?))
            })
            .map(make)
        };
        let switches = |cmd, make: fn(Vec<(AxisId, bool)>) -> Self| {
            groups::<2, _>(cmd, args, |c| {
                Ok((AxisId::new(c[0])?, parse_switch(cmd, c[1])?))
            })
            .map(make)
        };
        Some(match mnemonic {
            "SVO" => switches("SVO", Self::Svo),
            "RON" => switches("RON", Self::Ron),
            "MOV" => numbers("MOV", Self::Mov),
            "MVR" => numbers("MVR", Self::Mvr),
            "VEL" => numbers("VEL", Self::Vel),
            "ACC" => numbers("ACC", Self::Acc),
            "DEC" => numbers("DEC", Self::Dec),
            _ => return None,
        })
    }

    /// The data recorder's and the parameters' commands.
    fn tables_and_parameters(mnemonic: &str, args: &[&str]) -> Option<Result<Self, CommandError>> {
        let c = || -> Result<Option<Self>, CommandError> {
            Ok(Some(match mnemonic {
                "RTR" => match args {
                    [r] => Self::Rtr(parse_u32("RTR", r)?),
                    _ => return Err(CommandError::ArgCount { cmd: "RTR" }),
                },
                "DRC?" => Self::DrcQuery(u32_list("DRC?", args)?),
                "DRL?" => Self::DrlQuery(u32_list("DRL?", args)?),
                "DRC" => Self::Drc(groups::<3, _>("DRC", args, |c| {
                    Ok((
                        parse_u32("DRC", c[0])?,
                        AxisId::new(c[1])?,
                        parse_u32("DRC", c[2])?,
                    ))
                })?),
                "DRT" => Self::Drt(groups::<3, _>("DRT", args, |c| {
                    Ok((
                        parse_u32("DRT", c[0])?,
                        parse_u32("DRT", c[1])?,
                        c[2].to_owned(),
                    ))
                })?),
                "DRR?" => Self::drr_query(&u32_list("DRR?", args)?),
                "SAI?" => match args {
                    [] => Self::SaiQuery { all: false },
                    ["ALL"] => Self::SaiQuery { all: true },
                    _ => return Err(CommandError::ArgCount { cmd: "SAI?" }),
                },
                // Every parameter of every axis without arguments.
                "SPA?" if args.is_empty() => Self::SpaQuery(Vec::new()),
                "SPA?" => Self::SpaQuery(groups::<2, _>("SPA?", args, |c| {
                    Ok((AxisId::new(c[0])?, parse_param_id("SPA?", c[1])?))
                })?),
                "SPA" => Self::Spa(groups::<3, _>("SPA", args, |c| {
                    Ok((
                        AxisId::new(c[0])?,
                        parse_param_id("SPA", c[1])?,
                        c[2].to_owned(),
                    ))
                })?),
                _ => return Ok(None),
            }))
        };
        c().transpose()
    }

    /// `DRR?` from its numbers: start point, count, then tables.
    fn drr_query(nums: &[u32]) -> Self {
        match nums {
            [] => Self::DrrQuery {
                start: None,
                count: None,
                tables: Vec::new(),
            },
            [a] => Self::DrrQuery {
                start: Some(*a),
                count: None,
                tables: Vec::new(),
            },
            [a, n, t @ ..] => Self::DrrQuery {
                start: Some(*a),
                count: Some(*n),
                tables: t.to_vec(),
            },
        }
    }
}

/// Arguments read in groups of `N` by `read`: at least one group, and no
/// argument left over (else `ArgCount`).
fn groups<const N: usize, T>(
    cmd: &'static str,
    args: &[&str],
    read: impl Fn(&[&str]) -> Result<T, CommandError>,
) -> Result<Vec<T>, CommandError> {
    if args.is_empty() || args.len() % N != 0 {
        return Err(CommandError::ArgCount { cmd });
    }
    args.chunks(N).map(read).collect()
}

/// A switch argument: `0` off, `1` on.
fn parse_switch(cmd: &'static str, s: &str) -> Result<bool, CommandError> {
    match s {
        "0" => Ok(false),
        "1" => Ok(true),
        other => Err(CommandError::BadNumber {
            cmd,
            arg: other.to_owned(),
        }),
    }
}

fn parse_f64(cmd: &'static str, s: &str) -> Result<f64, CommandError> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(CommandError::BadNumber {
            cmd,
            arg: s.to_owned(),
        }),
    }
}

fn parse_u32(cmd: &'static str, s: &str) -> Result<u32, CommandError> {
    s.parse::<u32>().map_err(|_| CommandError::BadNumber {
        cmd,
        arg: s.to_owned(),
    })
}

fn u32_list(cmd: &'static str, args: &[&str]) -> Result<Vec<u32>, CommandError> {
    args.iter().map(|a| parse_u32(cmd, a)).collect()
}

/// Parses a parameter id, written in hex (`0x3C`) or decimal (`60`).
pub fn parse_param_id(cmd: &'static str, s: &str) -> Result<u32, CommandError> {
    let r = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => s.parse::<u32>(),
    };
    r.map_err(|_| CommandError::BadNumber {
        cmd,
        arg: s.to_owned(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn ax(s: &str) -> AxisId {
        AxisId::new(s).unwrap()
    }

    #[test]
    fn text_forms() {
        assert_eq!(Command::Mov(vec![(ax("1"), 12.5)]).to_text(), "MOV 1 12.5");
        assert_eq!(
            Command::Mvr(vec![(ax("1"), -0.0001)]).to_text(),
            "MVR 1 -0.0001"
        );
        assert_eq!(Command::PosQuery(vec![ax("1")]).to_text(), "POS? 1");
        assert_eq!(Command::PosQuery(vec![]).to_text(), "POS?");
        assert_eq!(Command::SaiQuery { all: true }.to_text(), "SAI? ALL");
        assert_eq!(Command::Svo(vec![(ax("1"), true)]).to_text(), "SVO 1 1");
        assert_eq!(
            Command::SpaQuery(vec![(ax("1"), 0x3C)]).to_text(),
            "SPA? 1 0x3C"
        );
        assert_eq!(
            Command::Spa(vec![(ax("1"), 0x3C, "M-111.1DG".into())]).to_text(),
            "SPA 1 0x3C M-111.1DG"
        );
        assert_eq!(format_number(1e-9), "0");
        assert_eq!(format_number(-1e-9), "0");
        assert_eq!(format_number(15.0), "15");
        assert!(Command::Idn.is_query());
        assert!(!Command::Stp.is_query());
    }

    #[test]
    fn parsing_and_errors() {
        assert_eq!(
            Command::parse("MOV 1 3.5").unwrap(),
            Command::Mov(vec![(ax("1"), 3.5)])
        );
        assert_eq!(Command::parse("FRF").unwrap(), Command::Frf(vec![]));
        assert_eq!(
            Command::parse("SPA? 1 0x3c").unwrap(),
            Command::SpaQuery(vec![(ax("1"), 0x3C)])
        );
        assert_eq!(Command::parse("SPA?").unwrap(), Command::SpaQuery(vec![]));
        assert!(matches!(
            Command::parse("XYZ?"),
            Err(CommandError::Unknown(_))
        ));
        assert!(matches!(Command::parse(""), Err(CommandError::Unknown(_))));
        assert!(matches!(
            Command::parse("MOV 1"),
            Err(CommandError::ArgCount { .. })
        ));
        assert!(matches!(
            Command::parse("MOV 1 abc"),
            Err(CommandError::BadNumber { .. })
        ));
        assert!(matches!(
            Command::parse("MOV 1 inf"),
            Err(CommandError::BadNumber { .. })
        ));
        assert!(matches!(
            Command::parse("SVO 1 2"),
            Err(CommandError::BadNumber { .. })
        ));
        assert!(matches!(
            Command::parse("POS? a-b"),
            Err(CommandError::BadAxis(_))
        ));
        assert!(matches!(
            Command::parse("*IDN? x"),
            Err(CommandError::ArgCount { .. })
        ));
        assert_eq!(CommandError::Unknown("X".into()).gcs_code().0, 2);
        // The data recorder, as PIPython sends it.
        assert_eq!(
            Command::parse("DRC 1 1 2").unwrap(),
            Command::Drc(vec![(1, ax("1"), 2)])
        );
        assert_eq!(
            Command::parse("DRR? 1 512 1").unwrap(),
            Command::DrrQuery {
                start: Some(1),
                count: Some(512),
                tables: vec![1]
            }
        );
        assert_eq!(Command::parse("DRT 0 4 0").unwrap().to_text(), "DRT 0 4 0");
        assert!(matches!(
            Command::parse("RTR -1"),
            Err(CommandError::BadNumber { .. })
        ));
        assert!(matches!(
            Command::parse("DRC 1 1"),
            Err(CommandError::ArgCount { .. })
        ));
    }

    fn any_axis() -> impl Strategy<Value = AxisId> + Clone {
        "[0-9A-Za-z_]{1,8}".prop_map(|s| AxisId::new(&s).unwrap())
    }

    fn any_command() -> impl Strategy<Value = Command> {
        let axes = proptest::collection::vec(any_axis(), 0..3);
        let fpairs = proptest::collection::vec((any_axis(), -1e4f64..1e4), 1..3);
        prop_oneof![
            Just(Command::Idn),
            Just(Command::Err),
            Just(Command::Stp),
            any::<bool>().prop_map(|all| Command::SaiQuery { all }),
            axes.clone().prop_map(Command::PosQuery),
            axes.clone().prop_map(Command::Frf),
            axes.prop_map(Command::Hlt),
            fpairs.clone().prop_map(Command::Mov),
            fpairs.prop_map(Command::Vel),
            proptest::collection::vec((any_axis(), any::<bool>()), 1..3).prop_map(Command::Svo),
            proptest::collection::vec((any_axis(), 0u32..0xFFFF_FFFF), 0..3)
                .prop_map(Command::SpaQuery),
            Just(Command::TnrQuery),
            Just(Command::RtrQuery),
            any::<u32>().prop_map(Command::Rtr),
            proptest::collection::vec((0u32..9, any_axis(), 0u32..30), 1..3).prop_map(Command::Drc),
            proptest::collection::vec((0u32..9, 0u32..10, "[0-9]{1,3}"), 1..3)
                .prop_map(Command::Drt),
            proptest::collection::vec(0u32..9, 0..3).prop_map(Command::DrlQuery),
            (
                any::<u32>(),
                any::<u32>(),
                proptest::collection::vec(0u32..9, 0..3)
            )
                .prop_map(|(a, n, tables)| Command::DrrQuery {
                    start: Some(a),
                    count: Some(n),
                    tables
                }),
        ]
    }

    proptest! {
        #[test]
        fn parse_never_panics(s in "\\PC{0,80}") {
            let _ = Command::parse(&s);
        }

        #[test]
        fn text_round_trips(c in any_command()) {
            let parsed = Command::parse(&c.to_text()).unwrap();
            match (&c, &parsed) {
                (Command::Mov(a), Command::Mov(b)) | (Command::Vel(a), Command::Vel(b)) => {
                    for ((ax1, v1), (ax2, v2)) in a.iter().zip(b) {
                        prop_assert_eq!(ax1, ax2);
                        prop_assert!((v1 - v2).abs() <= 5e-8);
                    }
                }
                _ => prop_assert_eq!(&c, &parsed),
            }
        }
    }
}
