//! The C-863's data recorder: [`TABLES`] record tables of [`TABLE_POINTS`]
//! points each, sampling the axis every `RTR` servo cycles
//! ([`SERVO_CYCLE_S`]) on the rig clock from the instant of their trigger
//! until full. Commands: `DRC`/`DRC?` (source axis and record option),
//! `RTR`/`RTR?`, `DRT` (trigger: immediately, or the next move), `DRL?`,
//! `DRR?` (GCS array data, `micropos::gcs::recorder`), `TNR?`, `HDR?`.
//!
//! Why sampled when a request arrives and not on a tick: the controller
//! has no tick (closed-form motion, see the module above). Every request
//! first records the samples due since the last one from the trajectory in
//! force (`Controller::tick`), and a trajectory only changes while a
//! request is handled, so each sample is the servo's state at its own
//! instant. Memory is bounded by the tables' length, as on the controller.

use micropos::gcs::recorder::{
    encode_records, RECORD_ACTUAL_POSITION, RECORD_COMMANDED_POSITION, RECORD_POSITION_ERROR,
    TRIGGER_DEFAULT, TRIGGER_IMMEDIATELY, TRIGGER_POSITION_CHANGING_COMMAND,
};
use micropos::gcs::AxisId;
use micropos::gcs::GcsErrorCode as E;
use std::time::Duration;

/// Record tables (`TNR?`).
pub const TABLES: usize = 2;
/// Points per record table (a C-863's, PIPython's `MAXNUMVALUES`).
pub const TABLE_POINTS: usize = 1024;
/// The C-863.11's servo cycle, s (parameter 0x0E000200, PIPython's
/// `SERVOTIMES`).
pub const SERVO_CYCLE_S: f64 = 50e-6;

#[derive(Debug, Clone, Default)]
struct Table {
    /// Record option (0: nothing).
    option: u32,
    /// Trigger source.
    trigger: u32,
    /// Waiting for the next position-changing command.
    armed: bool,
    /// Instant of the trigger.
    started: Option<Duration>,
    values: Vec<f64>,
}

/// The recorder's state.
#[derive(Debug, Clone)]
pub(super) struct Recorder {
    tables: Vec<Table>,
    /// Servo cycles per record.
    rate: u32,
}

impl Default for Recorder {
    fn default() -> Self {
        Self {
            tables: vec![
                Table {
                    option: RECORD_ACTUAL_POSITION,
                    ..Table::default()
                };
                TABLES
            ],
            rate: 1,
        }
    }
}

/// What a sample reads at an instant: (actual, commanded) position, mm.
pub(super) type Probe<'a> = &'a dyn Fn(Duration) -> (f64, f64);

impl Recorder {
    fn sample_time_s(&self) -> f64 {
        f64::from(self.rate) * SERVO_CYCLE_S
    }

    /// Takes every sample due up to `now` with `probe`.
    pub(super) fn fill(&mut self, now: Duration, probe: Probe<'_>) {
        let dt = self.sample_time_s();
        for t in &mut self.tables {
            let Some(t0) = t.started else { continue };
            if t.option == 0 {
                continue;
            }
            while t.values.len() < TABLE_POINTS {
                let at = t0 + Duration::from_secs_f64(dt * t.values.len() as f64);
                if at > now {
                    break;
                }
                let (actual, commanded) = probe(at);
                t.values.push(match t.option {
                    RECORD_COMMANDED_POSITION => commanded,
                    RECORD_POSITION_ERROR => commanded - actual,
                    _ => actual,
                });
            }
        }
    }

    /// A position-changing command starts the tables armed for it.
    pub(super) fn on_move(&mut self, now: Duration) {
        for t in &mut self.tables {
            if t.armed {
                t.armed = false;
                t.started = Some(now);
                t.values.clear();
            }
        }
    }

    /// Table ids 1..=TABLES, or all for an empty list.
    fn ids(tables: &[u32]) -> Result<Vec<usize>, E> {
        if tables.is_empty() {
            return Ok((0..TABLES).collect());
        }
        tables
            .iter()
            .map(|&t| match t as usize {
                n @ 1..=TABLES => Ok(n - 1),
                _ => Err(E::PARAM_OUT_OF_RANGE),
            })
            .collect()
    }

    /// `DRC`.
    pub(super) fn configure(&mut self, items: &[(u32, AxisId, u32)], axis: &str) -> Result<(), E> {
        for (t, src, opt) in items {
            Self::ids(&[*t])?;
            if src.as_str() != axis {
                return Err(E::INVALID_AXIS);
            }
            if !matches!(
                *opt,
                0 | RECORD_COMMANDED_POSITION | RECORD_ACTUAL_POSITION | RECORD_POSITION_ERROR
            ) {
                return Err(E::PARAM_OUT_OF_RANGE);
            }
        }
        for (t, _, opt) in items {
            let tab = &mut self.tables[*t as usize - 1];
            tab.option = *opt;
            tab.started = None;
            tab.armed = false;
            tab.values.clear();
        }
        Ok(())
    }

    /// `DRC?`.
    pub(super) fn configuration(&self, tables: &[u32], axis: &str) -> Result<Vec<String>, E> {
        Ok(Self::ids(tables)?
            .into_iter()
            .map(|i| format!("{}={axis} {}", i + 1, self.tables[i].option))
            .collect())
    }

    /// `RTR`.
    pub(super) fn set_rate(&mut self, rate: u32) -> Result<(), E> {
        if rate == 0 || rate > 1_000_000 {
            return Err(E::PARAM_OUT_OF_RANGE);
        }
        self.rate = rate;
        Ok(())
    }

    /// `RTR?`.
    pub(super) fn rate(&self) -> u32 {
        self.rate
    }

    /// `DRT`: table 0 sets every table.
    pub(super) fn trigger(&mut self, now: Duration, items: &[(u32, u32, String)]) -> Result<(), E> {
        for (t, src, _) in items {
            if *t != 0 {
                Self::ids(&[*t])?;
            }
            if !matches!(
                *src,
                TRIGGER_DEFAULT | TRIGGER_POSITION_CHANGING_COMMAND | TRIGGER_IMMEDIATELY
            ) {
                return Err(E::PARAM_OUT_OF_RANGE);
            }
        }
        for (t, src, _) in items {
            let ids = if *t == 0 {
                (0..TABLES).collect()
            } else {
                vec![*t as usize - 1]
            };
            for i in ids {
                let tab = &mut self.tables[i];
                tab.trigger = *src;
                tab.values.clear();
                if *src == TRIGGER_IMMEDIATELY {
                    tab.armed = false;
                    tab.started = Some(now);
                } else {
                    tab.armed = true;
                    tab.started = None;
                }
            }
        }
        Ok(())
    }

    /// `DRL?`.
    pub(super) fn lengths(&self, tables: &[u32]) -> Result<Vec<String>, E> {
        Ok(Self::ids(tables)?
            .into_iter()
            .map(|i| format!("{}={}", i + 1, self.tables[i].values.len()))
            .collect())
    }

    /// `DRR?`: `start` is 1-based; the rows are those every table read
    /// has (from `start`, at most `count`).
    pub(super) fn read(
        &self,
        start: Option<u32>,
        count: Option<u32>,
        tables: &[u32],
        axis: &str,
    ) -> Result<Vec<String>, E> {
        let ids = Self::ids(tables)?;
        let start = start.unwrap_or(1);
        if start == 0 {
            return Err(E::PARAM_OUT_OF_RANGE);
        }
        let from = start as usize - 1;
        let cols: Vec<(String, Vec<f64>)> = ids
            .iter()
            .map(|&i| {
                let t = &self.tables[i];
                let have = t.values.get(from..).unwrap_or_default();
                let n = count.map_or(have.len(), |c| (c as usize).min(have.len()));
                (
                    format!("{} of {axis}", option_name(t.option)),
                    have[..n].to_vec(),
                )
            })
            .collect();
        Ok(encode_records(self.sample_time_s(), &cols))
    }

    /// `HDR?`, in the layout PIPython's `get_hdr_options` reads.
    pub(super) fn help() -> Vec<String> {
        vec![
            "#RecordOptions".to_owned(),
            "0=Nothing is recorded".to_owned(),
            format!("{RECORD_COMMANDED_POSITION}=Commanded Position of Axis"),
            format!("{RECORD_ACTUAL_POSITION}=Real Position of Axis"),
            format!("{RECORD_POSITION_ERROR}=Position Error of Axis"),
            "#TriggerOptions".to_owned(),
            format!("{TRIGGER_DEFAULT}=Default setting"),
            format!("{TRIGGER_POSITION_CHANGING_COMMAND}=Any command changing position (e.g. MOV)"),
            format!("{TRIGGER_IMMEDIATELY}=Trigger immediately"),
            "#Additional information".to_owned(),
            format!("{TABLE_POINTS} datapoints per table"),
            "end of help".to_owned(),
        ]
    }
}

fn option_name(option: u32) -> &'static str {
    match option {
        RECORD_COMMANDED_POSITION => "Commanded Position",
        RECORD_ACTUAL_POSITION => "Actual Position",
        RECORD_POSITION_ERROR => "Position Error",
        _ => "Nothing",
    }
}
