//! The daemon's shared parts and what they do with a command: one
//! [`Daemon`] that the socket server and the web listener both call
//! ([`Daemon::execute`]), the reload of a changed configuration, and the
//! `drift` and job-cancel commands.

use super::config::DaemonConfig;
use super::protocol::{
    self, to_value, CharacterizeAction, Command, ConfigReply, DriftAction, DriftReply, ErrorCode,
    JobCancelReply, JobObject, JobReply, ProtoError, ReferenceReply, TablesAction, ValidateAction,
    VersionReply,
};
use super::{access, audit, figures, jobs, reload, rig};
use serde::Serialize;
use serde_json::Value;
use std::sync::Arc;
use tokio::sync::broadcast;

/// A typed reply as the value `protocol::reply` writes.
fn typed<T: Serialize>(reply: T) -> Result<Value, ProtoError> {
    Ok(to_value(&reply))
}

/// The running daemon's shared parts.
#[derive(Debug)]
pub struct Daemon {
    /// The rig.
    pub rig: Arc<rig::Rig>,
    /// Jobs.
    pub jobs: jobs::Jobs,
    /// Sends shutdown to every task.
    pub shutdown: broadcast::Sender<()>,
    /// Client roles (`[access]`, reloadable).
    pub access: access::Access,
    /// The audit trail of state-changing commands.
    pub audit: audit::Audit,
}

impl Daemon {
    /// Executes one command (everything but `subscribe`, which the server
    /// handles per connection).
    pub async fn execute(&self, cmd: Command) -> Result<Value, ProtoError> {
        let rig = &self.rig;
        match cmd {
            Command::Version => typed(VersionReply {
                daemon: env!("CARGO_PKG_VERSION").to_owned(),
                protocol: protocol::PROTOCOL_VERSION,
                commands: protocol::COMMANDS.iter().map(|&c| c.to_owned()).collect(),
            }),
            Command::Status => {
                let mut s = rig.status();
                s.job = self.jobs.status().map(JobObject::from);
                typed(s)
            }
            Command::Drift(a) => typed(self.drift(a).await?),
            Command::Position => typed(rig.position().await),
            Command::Move(m) => typed(rig.move_to(&m, false).await?),
            Command::Stop => {
                self.jobs.signal_cancel();
                typed(rig.stop().await?)
            }
            Command::Reset => typed(rig.reset()),
            Command::Reference(axes) => {
                // The reference run, then the rig's vision tie
                // (`daemon::vision_tie`): its outcome is part of the reply.
                let reported = rig.reference(axes).await?;
                typed(ReferenceReply {
                    reported,
                    vision_tie: jobs::tie::after_reference(rig).await,
                })
            }
            Command::Config => serde_json::to_value(self.effective_config())
                .map(|config| to_value(&ConfigReply { config }))
                .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string())),
            Command::Characterize(a) => match a {
                CharacterizeAction::Start(p) => typed(self.jobs.start(rig, *p).await?),
                CharacterizeAction::Resume { log } => typed(self.jobs.resume(rig, &log).await?),
                CharacterizeAction::Status => {
                    typed(JobReply::job(self.jobs.status().map(JobObject::from)))
                }
                CharacterizeAction::Cancel => typed(self.cancel_job().await?),
            },
            Command::Validate(v) => match v {
                ValidateAction::Status => typed(self.jobs.validation_status()),
                ValidateAction::Start(p) => typed(self.jobs.start_validation(rig, p).await?),
                ValidateAction::Cancel => typed(self.cancel_job().await?),
            },
            Command::Tables(t) => match t {
                TablesAction::List => typed(rig.comp.list(&rig.cfg.daemon.data_dir).await?),
                TablesAction::Load { name } => {
                    typed(rig.comp.load(&rig.cfg.daemon.data_dir, &name).await?)
                }
                TablesAction::Activate { name } => typed(rig.comp.activate(name.as_deref())?),
                TablesAction::Build(p) => {
                    self.jobs.check_log_finished(&p.log)?;
                    jobs::tables::build(rig, p).await
                }
            },
            Command::Figures(p) => figures::figures(&rig.cfg.daemon.data_dir, p).await,
            Command::Subscribe(_) => Err(ProtoError::new(
                ErrorCode::Internal,
                "subscribe is handled by the connection",
            )),
        }
    }

    /// The configuration in force: the file read at start with the
    /// running values of the reloadable sections.
    pub fn effective_config(&self) -> DaemonConfig {
        let mut c = self.rig.live.effective(&self.rig.cfg);
        c.access = self.access.current();
        c
    }

    /// Applies a reloaded configuration (SIGHUP): the changed keys of the
    /// reloadable sections take effect (limits and compensation from the
    /// next move, drift settings now, roles for new connections); other
    /// changed keys keep their running values and are reported as refused.
    /// A client's `drift set` survives a reload that leaves `[drift]`
    /// unchanged in the file.
    pub fn reload(&self, new: &DaemonConfig) -> reload::ReloadReport {
        let running = self.effective_config();
        let (applied, refused): (Vec<String>, Vec<String>) = reload::diff_keys(&running, new)
            .into_iter()
            .partition(|k| reload::is_reloadable(k));
        let changed = |section: &str| {
            applied
                .iter()
                .any(|k| k == section || k.starts_with(&format!("{section}.")))
        };
        let mut merged = running;
        merged.limits = new.limits;
        merged.compensation = new.compensation.clone();
        merged.drift = new.drift.clone();
        self.rig.live.set(&merged);
        if changed("drift") {
            let d = &new.drift;
            if let Err(e) = self.rig.drift.set(
                &merged,
                Some(d.method),
                Some(d.every_s),
                Some(d.time_constant_s),
            ) {
                tracing::warn!("reload: [drift] not applied: {e}");
            }
        }
        if changed("access") {
            self.access.set(new.access.clone());
        }
        reload::ReloadReport { applied, refused }
    }

    /// `characterize|validate cancel`: ends the job and halts both axes
    /// (waiting until they are at rest): the job's move in flight is
    /// dropped with its future, and the stage must not finish it alone.
    async fn cancel_job(&self) -> Result<JobCancelReply, ProtoError> {
        self.jobs.signal_cancel();
        let halt = self.rig.halt_and_wait("job cancelled").await;
        let job = self.jobs.cancel().await?;
        Ok(JobCancelReply {
            job: job.map(JobObject::from),
            halt,
        })
    }

    /// `drift show|set|reset|measure`.
    async fn drift(&self, a: DriftAction) -> Result<DriftReply, ProtoError> {
        let rig = &self.rig;
        let mut measured = None;
        match a {
            DriftAction::Show => {}
            DriftAction::Set {
                method,
                every_s,
                time_constant_s,
            } => rig.drift.set(&rig.cfg, method, every_s, time_constant_s)?,
            DriftAction::Reset => rig.drift.reset(),
            DriftAction::Measure => {
                if self.jobs.is_running() {
                    return Err(ProtoError::new(
                        ErrorCode::Busy,
                        "a job is running; it re-measures the reference itself",
                    ));
                }
                let active = rig.comp.active().ok_or_else(|| {
                    ProtoError::new(
                        ErrorCode::NoActiveTable,
                        "drift is measured against the active table's baseline: tables activate NAME",
                    )
                })?;
                let k = &rig.cfg.characterize;
                let r = rig
                    .drift_measure(&active, k.frames_per_point, k.settle_s, false)
                    .await?;
                measured = Some(to_value(&r.sample));
            }
        }
        Ok(DriftReply {
            drift: rig.drift.to_json(rig.clock.now_s()),
            measured,
        })
    }
}
