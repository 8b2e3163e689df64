//! microposd: the micropos service. Owns the controllers and the camera and
//! serves the local socket API (docs/socket-protocol.md). Runs under
//! systemd (`Type=notify`, socket activation supported) or by hand.
//!
//! SIGHUP reloads the configuration file (`Daemon::reload`: limits,
//! compensation, drift, access roles) and logs the keys it cannot change
//! live. `--halt` needs no running daemon: it opens the configured controller
//! lines, stops both axes with `#24` and waits (bounded by
//! `safety.halt_wait_s`) until they rest; the unit runs it as
//! `ExecStopPost=`, so a SIGKILL, crash or watchdog kill leaves no move
//! running. On SIGTERM/SIGINT the daemon halts both axes itself before it
//! exits.
//!
//! Exit codes: 0 clean shutdown (`--halt`: both axes at rest), 1 runtime
//! failure (`--halt`: an axis not confirmed at rest), 2 bad configuration or
//! arguments.

use anyhow::Context;
use clap::Parser;
use micropos::camera::{files::FileOptions, open_source, OpenOptions};
use micropos::clock::{RigClock, SimClock, WallClock};
use micropos::daemon::config::ClockSpec;
use micropos::daemon::{config::DaemonConfig, notify, Daemon};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

/// The micropos daemon.
#[derive(Debug, Parser)]
#[command(name = "microposd", version, about)]
struct Args {
    /// Configuration file.
    #[arg(long, short, default_value = "/etc/micropos/microposd.toml")]
    config: PathBuf,
    /// Socket path (overrides daemon.socket).
    #[arg(long)]
    socket: Option<PathBuf>,
    /// Data directory (overrides daemon.data_dir).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Validate the configuration and exit.
    #[arg(long)]
    check_config: bool,
    /// Stop both axes (`#24` on the configured lines, no daemon needed),
    /// wait until they rest, and exit (0: both at rest).
    #[arg(long, conflicts_with = "check_config")]
    halt: bool,
}

/// `--halt`: see the module header.
async fn halt(cfg: DaemonConfig) -> bool {
    let wait = Duration::try_from_secs_f64(cfg.safety.halt_wait_s).unwrap_or_default();
    let report = micropos::driver::halt::halt_all(&cfg.driver, None, wait).await;
    let mut ok = true;
    for a in &report {
        let err = a
            .error
            .map(|c| c.0.to_string())
            .unwrap_or_else(|| "-".to_owned());
        if a.ok() {
            tracing::info!(
                "halt: axis {} stopped (#24) and at rest; ERR? {err}",
                a.axis
            );
        } else {
            ok = false;
            tracing::error!(
                "halt: axis {}: sent {}, at rest {}: {}",
                a.axis,
                a.sent,
                a.at_rest,
                a.problem.as_deref().unwrap_or("?")
            );
        }
    }
    ok
}

fn init_logging() {
    // Under systemd stderr goes to the journal (JOURNAL_STREAM is set):
    // no colours, no timestamps (journald adds its own). Elsewhere colour
    // only on a terminal and without NO_COLOR (`micropos::stderr_colour`).
    let journald = std::env::var_os("JOURNAL_STREAM").is_some();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let b = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .with_ansi(!journald && micropos::stderr_colour());
    if journald {
        b.without_time().init();
    } else {
        b.init();
    }
}

/// A socket passed by systemd (LISTEN_FDS), if any.
fn activated_listener() -> anyhow::Result<Option<std::os::unix::net::UnixListener>> {
    let fds: Vec<_> = sd_notify_listen_fds()?;
    match fds.as_slice() {
        [] => Ok(None),
        [fd] => {
            use std::os::fd::FromRawFd;
            // SAFETY: systemd passed this descriptor to us (LISTEN_PID is
            // ours, checked by listen_fds) and nothing else in the process
            // owns it; we take ownership exactly once.
            #[allow(unsafe_code)]
            let l = unsafe { std::os::unix::net::UnixListener::from_raw_fd(*fd) };
            Ok(Some(l))
        }
        more => anyhow::bail!(
            "systemd passed {} sockets; microposd.socket must have exactly one ListenStream",
            more.len()
        ),
    }
}

fn sd_notify_listen_fds() -> anyhow::Result<Vec<i32>> {
    Ok(sd_notify::listen_fds()
        .context("reading LISTEN_FDS")?
        .collect())
}

/// Binds the socket: refuses to steal it from a running daemon, removes a
/// stale one, sets the configured mode (group access for the `micropos`
/// group: the socket's group is the daemon's primary group).
///
/// The socket is bound in a fresh private (0700) directory next to `path`,
/// given its mode there, and renamed into place: no client can reach it
/// before it has its final mode, whatever the umask (binding at `path` and
/// then chmod'ing leaves a window as wide as the umask allows).
fn bind(path: &Path, mode: u32) -> anyhow::Result<std::os::unix::net::UnixListener> {
    if path.exists() {
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            anyhow::bail!("{} is in use by a running daemon", path.display());
        }
        std::fs::remove_file(path)
            .with_context(|| format!("removing stale socket {}", path.display()))?;
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    remove_stale_bind_dirs(dir);
    let private = tempfile::Builder::new()
        .prefix(BIND_PREFIX)
        .tempdir_in(dir)
        .with_context(|| format!("creating a private directory in {}", dir.display()))?;
    let staged = private.path().join("socket");
    let l = std::os::unix::net::UnixListener::bind(&staged)
        .with_context(|| format!("binding {}", staged.display()))?;
    std::fs::set_permissions(&staged, std::fs::Permissions::from_mode(mode))
        .with_context(|| format!("setting mode {mode:o} on {}", staged.display()))?;
    std::fs::rename(&staged, path)
        .with_context(|| format!("moving the socket into place at {}", path.display()))?;
    Ok(l)
}

/// How long a daemon on a simulated rig waits for `hil-sim serve` to come
/// up (its control socket answers last, after the lines and the camera).
const SIM_CLOCK_WAIT: Duration = Duration::from_secs(30);

/// Name prefix of [`bind`]'s private directories.
const BIND_PREFIX: &str = ".microposd-bind-";

/// Removes the empty private directories that a daemon killed between the
/// socket's rename and the directory's removal left next to the socket.
/// Only empty ones (`remove_dir` refuses any other), never through a
/// symbolic link: a directory with something in it is not ours to judge.
fn remove_stale_bind_dirs(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let ours = e.file_name().to_string_lossy().starts_with(BIND_PREFIX);
        if ours && e.file_type().is_ok_and(|t| t.is_dir()) && std::fs::remove_dir(e.path()).is_ok()
        {
            tracing::info!(
                "removed {}, left empty by an earlier daemon that stopped while binding",
                e.path().display()
            );
        }
    }
}

/// A socket every local user may connect to, with no `[access]` section to
/// give roles, makes every local user an admin: legal (a single-user lab
/// machine), but said at start.
fn warn_open_socket(cfg: &DaemonConfig, mode: u32) {
    if mode & 0o002 != 0 && cfg.access.is_none() {
        tracing::warn!(
            "daemon.socket_mode {mode:04o} lets every local user connect, and with no \
             [access] section every client is admin (it can move the stage); \
             use 0660 and the socket's group, or add [access]"
        );
    }
}

/// Where the configuration comes from, for the start and every reload.
#[derive(Debug, Clone)]
struct ConfigSource {
    path: PathBuf,
    socket: Option<PathBuf>,
    data_dir: Option<PathBuf>,
}

impl ConfigSource {
    /// Reads and validates the file, then applies the command line's
    /// overrides (so a reload does not see them as changes).
    fn load(&self) -> Result<DaemonConfig, micropos::daemon::config::ConfigError> {
        let mut cfg = DaemonConfig::load(&self.path)?;
        if let Some(s) = &self.socket {
            cfg.daemon.socket = s.clone();
        }
        if let Some(d) = &self.data_dir {
            cfg.daemon.data_dir = d.clone();
        }
        Ok(cfg)
    }
}

/// SIGHUP: re-reads the file; applies what can change live, names what
/// cannot; a bad file changes nothing. Never ends the daemon.
async fn reload(daemon: &Daemon, source: &ConfigSource) {
    notify::reloading();
    let s = source.clone();
    let loaded = tokio::task::spawn_blocking(move || s.load()).await;
    match loaded {
        Ok(Ok(cfg)) => {
            let r = daemon.reload(&cfg);
            if r.applied.is_empty() && r.refused.is_empty() {
                tracing::info!("SIGHUP: {} unchanged", source.path.display());
            }
            if !r.applied.is_empty() {
                tracing::info!(keys = %r.applied.join(" "), "SIGHUP: reloaded {}", r.applied.join(", "));
            }
            if !r.refused.is_empty() {
                tracing::warn!(
                    keys = %r.refused.join(" "),
                    "SIGHUP: not reloadable, restart to apply (running values kept): {}",
                    r.refused.join(", ")
                );
            }
        }
        // The error names the file, line and key.
        Ok(Err(e)) => tracing::error!("SIGHUP: {e}; the running configuration stays"),
        Err(e) => tracing::error!("SIGHUP: reading the configuration failed: {e}"),
    }
    notify::ready();
}

async fn run(cfg: DaemonConfig, source: ConfigSource) -> anyhow::Result<()> {
    let mode = cfg.socket_mode()?;
    let (std_listener, owned_path) = match activated_listener()? {
        Some(l) => {
            tracing::info!("using the socket passed by systemd");
            (l, None)
        }
        None => (
            {
                warn_open_socket(&cfg, mode);
                bind(&cfg.daemon.socket, mode)?
            },
            Some(cfg.daemon.socket.clone()),
        ),
    };
    std_listener.set_nonblocking(true)?;
    let listener = tokio::net::UnixListener::from_std(std_listener)?;
    std::fs::create_dir_all(&cfg.daemon.data_dir)
        .with_context(|| format!("creating data_dir {}", cfg.daemon.data_dir.display()))?;
    let clock: Arc<dyn RigClock> = match cfg.clock_spec()? {
        ClockSpec::Wall => Arc::new(WallClock::new()),
        ClockSpec::Sim(path) => {
            let p = path.clone();
            let c =
                tokio::task::spawn_blocking(move || SimClock::connect_waiting(&p, SIM_CLOCK_WAIT))
                    .await?
                    .with_context(|| {
                        format!("connecting the sim clock (rig.clock) at {}", path.display())
                    })?;
            Arc::new(c)
        }
    };
    let camera = match cfg.camera_source()? {
        Some(spec) => {
            let opts = OpenOptions {
                timeout: Duration::from_millis(cfg.camera.timeout_ms),
                files: FileOptions {
                    looping: cfg.camera.looping,
                    ..FileOptions::default()
                },
            };
            let s = tokio::task::spawn_blocking(move || open_source(&spec, &opts))
                .await?
                .context("opening the camera (camera.source)")?;
            Some(s)
        }
        None => None,
    };
    let running = Daemon::start(cfg, clock, camera, listener)?;
    tracing::info!("microposd {} listening", env!("CARGO_PKG_VERSION"));
    notify::ready();
    let wd = tokio::spawn(notify::watchdog_loop(
        running.daemon.clone(),
        running.daemon.shutdown.subscribe(),
    ));
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate())?;
    let mut hup = signal(SignalKind::hangup())?;
    loop {
        tokio::select! {
            _ = term.recv() => {
                tracing::info!("SIGTERM: halting both axes, then shutting down");
                break;
            }
            _ = tokio::signal::ctrl_c() => {
                tracing::info!("SIGINT: halting both axes, then shutting down");
                break;
            }
            _ = hup.recv() => reload(&running.daemon, &source).await,
        }
    }
    notify::stopping();
    running.shutdown().await;
    let _ = wd.await;
    if let Some(p) = owned_path {
        let _ = std::fs::remove_file(p);
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    init_logging();
    let source = ConfigSource {
        path: args.config.clone(),
        socket: args.socket,
        data_dir: args.data_dir,
    };
    let cfg = match source.load() {
        Ok(c) => c,
        // The error names the file (and line, column and key).
        Err(e) => {
            eprintln!("microposd: {e}");
            return ExitCode::from(2);
        }
    };
    // The web token file is part of the configuration: a missing, short or
    // group-readable one is a bad configuration (exit 2, and
    // --check-config says so before systemd starts the daemon).
    if let Some(Err(e)) = cfg.web.as_ref().map(|w| w.resolve_token()) {
        eprintln!("microposd: {}: {e}", args.config.display());
        return ExitCode::from(2);
    }
    if args.check_config {
        println!("{}: configuration is valid", args.config.display());
        return ExitCode::SUCCESS;
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        // Bounded so a burst of clients (each resolves its groups on the
        // blocking pool) stays within the unit's TasksMax.
        .max_blocking_threads(64)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("microposd: cannot start the runtime: {e}");
            return ExitCode::from(1);
        }
    };
    if args.halt {
        return if rt.block_on(halt(cfg)) {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        };
    }
    match rt.block_on(run(cfg, source)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let text = micropos::error_text(e.as_ref());
            tracing::error!("{text}");
            eprintln!("microposd: {text}");
            ExitCode::from(1)
        }
    }
}
