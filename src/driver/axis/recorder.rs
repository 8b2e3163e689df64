//! The controller's data recorder for one axis (`gcs::recorder`): a record
//! table sampling the axis's actual position every `RTR` servo cycles from
//! its trigger until full, read back in pieces. Used by the sweep
//! characterization where the controller has one (`TNR?` answers), for
//! positions denser and more evenly spaced than `POS?` polling.

use super::{read_value, Axis};
use crate::driver::error::DriverError;
use crate::driver::units::mm_to_um;
use crate::gcs::answer;
use crate::gcs::recorder::{parse_records, RECORD_ACTUAL_POSITION, TRIGGER_IMMEDIATELY};
use crate::gcs::{AxisId, Command, GcsErrorCode};

/// Records read back from one table.
#[derive(Debug, Clone, PartialEq)]
pub struct Records {
    /// Time between two records, s (the reply's `SAMPLE_TIME`).
    pub sample_time_s: f64,
    /// The axis's actual position per record, µm, in record order.
    pub positions_um: Vec<f64>,
    /// The connection epoch the reply was read on.
    pub epoch: u64,
}

impl Axis {
    /// `TNR?`: how many record tables the controller has, `None` if it
    /// does not know the command (a controller without a data recorder).
    pub async fn recorder_tables(&self) -> Result<Option<u32>, DriverError> {
        let cmd = Command::TnrQuery;
        match self.ctl().query(&cmd).await {
            Ok((a, _)) => match answer::single_number(&a) {
                Ok(n) if n >= 0.0 && n.fract() == 0.0 && n <= f64::from(u32::MAX) => {
                    Ok(Some(n as u32))
                }
                Ok(_) => Ok(None),
                Err(e) => Err(self.ctl().bad_answer(&cmd, &a, e).await),
            },
            Err(DriverError::Gcs { code, .. }) if code == GcsErrorCode::UNKNOWN_COMMAND => Ok(None),
            Err(e) => self.on_error(Err(e)),
        }
    }

    /// Sets record table `table` to record this axis's actual position
    /// every `rate` servo cycles (`DRC`, `RTR`). `RTR` is the controller's,
    /// shared by every table.
    pub async fn record_actual_position(&self, table: u32, rate: u32) -> Result<(), DriverError> {
        let axis: AxisId = self.inner.p.axis.clone();
        self.set(Command::Drc(vec![(table, axis, RECORD_ACTUAL_POSITION)]))
            .await?;
        self.set(Command::Rtr(rate)).await?;
        Ok(())
    }

    /// Starts table `table` now (`DRT table 4 0`): its first record is the
    /// position when the controller reads the command. Returns the
    /// connection epoch.
    pub async fn trigger_recorder(&self, table: u32) -> Result<u64, DriverError> {
        self.set(Command::Drt(vec![(
            table,
            TRIGGER_IMMEDIATELY,
            "0".to_owned(),
        )]))
        .await
    }

    /// `DRL?`: records taken by `table` since its trigger.
    pub async fn recorded_points(&self, table: u32) -> Result<(u32, u64), DriverError> {
        let cmd = Command::DrlQuery(vec![table]);
        let key = AxisId::new(&table.to_string())
            .map_err(|e| DriverError::Invalid(format!("record table {table}: {e}")))?;
        let r = read_value(self.ctl(), &cmd, &key, |s| {
            s.trim()
                .parse::<u32>()
                .map_err(|_| answer::AnswerError::NotNumber(s.to_owned()))
        })
        .await;
        self.on_error(r)
    }

    /// `DRR? start count table`: `count` records of `table` from `start`
    /// (1-based), as µm.
    pub async fn read_records(
        &self,
        table: u32,
        start: u32,
        count: u32,
    ) -> Result<Records, DriverError> {
        let cmd = Command::DrrQuery {
            start: Some(start),
            count: Some(count),
            tables: vec![table],
        };
        let (a, epoch) = self.on_error(self.ctl().query(&cmd).await)?;
        let r = parse_records(&a.lines()).map_err(|e| DriverError::BadAnswer {
            command: cmd.to_text(),
            detail: e.to_string(),
            text: a.text().chars().take(200).collect(),
        })?;
        let Some(col) = r.columns.first() else {
            return Err(DriverError::BadAnswer {
                command: cmd.to_text(),
                detail: "no column in the reply".to_owned(),
                text: a.text().chars().take(200).collect(),
            });
        };
        if r.columns.len() != 1 || col.len() > count as usize {
            return Err(DriverError::BadAnswer {
                command: cmd.to_text(),
                detail: format!(
                    "{} columns of {} rows for one table of at most {count}",
                    r.columns.len(),
                    col.len()
                ),
                text: a.text().chars().take(200).collect(),
            });
        }
        Ok(Records {
            sample_time_s: r.sample_time_s,
            positions_um: col.iter().map(|&mm| mm_to_um(mm)).collect(),
            epoch,
        })
    }
}
