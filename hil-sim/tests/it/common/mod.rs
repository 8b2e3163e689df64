//! Helpers shared by the hil-sim integration tests (the modules of
//! `main.rs`) that talk to a daemon over its Unix socket.

use hil_sim::{AxisName, ServeConfig, SimHandle};
use micropos::camera::{open_source, OpenOptions};
use micropos::clock::{RigClock, SimClock, WallClock};
use micropos::daemon::config::DaemonConfig;
use micropos::daemon::{Daemon, Running};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

/// How long a test waits for one line from the daemon before failing.
const LINE_TIMEOUT: Duration = Duration::from_secs(60);

/// A JSON-lines client of the daemon's socket with numbered requests.
/// Fields are public so a test can take the halves apart (half-close and
/// reconnect tests).
pub struct Client {
    /// Reading half, line-buffered.
    pub r: BufReader<tokio::net::unix::OwnedReadHalf>,
    /// Writing half.
    pub w: tokio::net::unix::OwnedWriteHalf,
    /// Id of the last request sent.
    pub next: u64,
}

impl Client {
    /// Connects to the daemon's socket at `p`.
    pub async fn connect(p: &Path) -> Client {
        let (r, w) = UnixStream::connect(p).await.unwrap().into_split();
        Client {
            r: BufReader::new(r),
            w,
            next: 0,
        }
    }

    /// Writes raw bytes (malformed-request tests).
    pub async fn send_raw(&mut self, b: &[u8]) {
        self.w.write_all(b).await.unwrap();
    }

    /// The next line from the daemon (reply or event), parsed.
    pub async fn line(&mut self) -> Value {
        let mut l = String::new();
        let n = tokio::time::timeout(LINE_TIMEOUT, self.r.read_line(&mut l))
            .await
            .unwrap()
            .unwrap();
        assert!(n > 0, "the daemon closed the connection");
        serde_json::from_str(&l).unwrap()
    }

    /// Sends `req` with the next id and returns its reply, whatever `ok`
    /// says (events in between are skipped).
    pub async fn call(&mut self, mut req: Value) -> Value {
        self.next += 1;
        req["id"] = json!(self.next);
        self.send_raw(format!("{req}\n").as_bytes()).await;
        loop {
            let v = self.line().await;
            if v.get("event").is_none() {
                assert_eq!(v["id"], json!(self.next), "{v}");
                return v;
            }
        }
    }

    /// [`Client::call`] that panics with the daemon's error unless `ok`.
    pub async fn call_ok(&mut self, req: Value) -> Value {
        let shown = req.to_string();
        let v = self.call(req).await;
        assert_eq!(v["ok"], true, "{shown} refused: {v}");
        v
    }
}

/// Starts microposd in-process with the validated config `c` on a served
/// rig: the rig's simulated clock through its control socket `control`, the
/// config's camera source, listening on `socket`.
pub async fn start_daemon(c: DaemonConfig, control: PathBuf, socket: &Path) -> Running {
    let clock = tokio::task::spawn_blocking(move || SimClock::connect(&control))
        .await
        .unwrap()
        .unwrap();
    let clock: Arc<dyn RigClock> = Arc::new(clock);
    let spec = c.camera_source().unwrap().unwrap();
    let oo = OpenOptions {
        timeout: Duration::from_millis(c.camera.timeout_ms),
        ..OpenOptions::default()
    };
    let camera = tokio::task::spawn_blocking(move || open_source(&spec, &oo))
        .await
        .unwrap()
        .unwrap();
    let listener = tokio::net::UnixListener::bind(socket).unwrap();
    Daemon::start(c, clock, Some(camera), listener).unwrap()
}

/// Starts the rig in process on the current runtime (a paused one in these
/// tests: the virtual clock, so a seed gives one result).
pub fn serve_in_process(cfg: ServeConfig) -> SimHandle {
    SimHandle::start_in_process(cfg).unwrap()
}

/// Starts microposd in-process with the validated config `c` on the
/// in-process rig `sim` (its clock, camera on demand and lines), listening
/// on `socket`.
pub fn start_daemon_in_process(c: DaemonConfig, sim: &SimHandle, socket: &Path) -> Running {
    let _ = std::fs::remove_file(socket);
    let listener = tokio::net::UnixListener::bind(socket).unwrap();
    Daemon::start_in(c, hil_sim::run::in_process_environment(sim), listener).unwrap()
}

/// Waits (up to 30 s) until the daemon reports both controllers
/// connected, then references both axes.
pub async fn connect_and_reference(cl: &mut Client) {
    let t0 = Instant::now();
    loop {
        let s = cl.call_ok(json!({"cmd": "status"})).await;
        if s["rig"]["connected"]["x"] == true && s["rig"]["connected"]["y"] == true {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "not connected: {s}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    cl.call_ok(json!({"cmd": "reference", "axes": "xy"})).await;
}

/// A served rig's config in `rig_dir` with its control and camera sockets
/// (`control.sock`, `camera.sock`) at `time_scale` and `seed`; callers set
/// the rest by struct update.
pub fn serve_config(rig_dir: &Path, time_scale: f64, seed: u64) -> ServeConfig {
    ServeConfig {
        link_dir: rig_dir.to_owned(),
        time_scale,
        control_socket: Some(rig_dir.join("control.sock")),
        camera_socket: Some(rig_dir.join("camera.sock")),
        seed,
        ..ServeConfig::default()
    }
}

/// An in-process rig (time scale 50, its virtual clock) and the main
/// job's daemon configuration for it (reduced plan), in a fresh temporary
/// directory: what the in-process daemon tests start from. `dir` must
/// outlive the test's use of the others (dropping it removes them).
pub struct InProcess {
    pub dir: tempfile::TempDir,
    pub data: PathBuf,
    pub socket: PathBuf,
    pub sim: SimHandle,
    pub rig: hil_sim::rig::RigConfig,
    pub config: DaemonConfig,
}

/// [`InProcess`] with the rig's `seed`.
pub fn in_process_rig(seed: u64) -> InProcess {
    in_process_rig_at(seed, 50.0)
}

/// [`InProcess`] with the rig's `seed` at `time_scale`.
pub fn in_process_rig_at(seed: u64, time_scale: f64) -> InProcess {
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    let cfg = serve_config(&rig_dir, time_scale, seed);
    let rig = cfg.rig.clone();
    let sim = serve_in_process(cfg);
    let socket = dir.path().join("d.sock");
    let config = hil_sim::run::daemon_config(
        &rig_dir,
        &data,
        &socket,
        &rig,
        &hil_sim::run::RunPlan::reduced(),
    )
    .unwrap();
    InProcess {
        dir,
        data,
        socket,
        sim,
        rig,
        config,
    }
}

/// Starts the served rig (on a blocking thread: it creates ptys and threads).
pub async fn serve(cfg: ServeConfig) -> SimHandle {
    tokio::task::spawn_blocking(move || SimHandle::start(cfg))
        .await
        .unwrap()
        .unwrap()
}

/// One HTTP/1.1 exchange with the daemon's web listener at `addr`
/// (`Connection: close`, the whole answer read): status, lower-cased
/// header block and body.
pub async fn http(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> (u16, String, Vec<u8>) {
    let s = tokio::net::TcpStream::connect(addr).await.unwrap();
    http_on(s, addr, method, path, headers, body).await
}

/// [`http`] on a stream already connected to `addr` (e.g. from a chosen
/// source address).
pub async fn http_on(
    mut s: tokio::net::TcpStream,
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> (u16, String, Vec<u8>) {
    use tokio::io::AsyncReadExt;
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(LINE_TIMEOUT, s.read_to_end(&mut out))
        .await
        .unwrap()
        .unwrap();
    let split = out
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP answer has a header block");
    let head = String::from_utf8_lossy(&out[..split]).to_lowercase();
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .expect("a status code");
    (status, head, out[split + 4..].to_vec())
}

/// A simulated rig with microposd on it: the one fixture of the tests that
/// drive the daemon through its socket. Two kinds: served on pseudo-
/// terminals in real time ([`DaemonRig::on_ptys`], the daemon's own driver
/// and wall clock), or in process on the test's paused runtime
/// ([`DaemonRig::in_process`], the main job's daemon configuration, both
/// axes referenced). Fields are public: a test may take the daemon or the
/// simulator out to stop it at a moment of its choosing.
pub struct DaemonRig {
    /// The simulator (`None` once taken).
    pub sim: Option<SimHandle>,
    /// The daemon (`None` once taken).
    pub daemon: Option<Running>,
    /// The daemon's socket.
    pub socket: PathBuf,
    /// The daemon's data directory.
    pub data: PathBuf,
    /// A served rig's threads and ptys end when the fixture is dropped; an
    /// in-process one ends with the test's runtime.
    served: bool,
    /// The temporary directory holding the socket, the data and a served
    /// rig's links.
    pub dir: tempfile::TempDir,
}

impl Drop for DaemonRig {
    fn drop(&mut self) {
        if self.served {
            if let Some(s) = self.sim.take() {
                s.shutdown();
            }
        }
    }
}

impl DaemonRig {
    /// The rig served on ptys (seed `seed`, `time_scale`), microposd on
    /// them with short driver timeouts and reconnects; `tune` adjusts the
    /// daemon's configuration last. Returns before the controllers are
    /// connected ([`DaemonRig::wait_connected`]).
    pub async fn on_ptys(
        seed: u64,
        time_scale: f64,
        tune: impl FnOnce(&mut DaemonConfig),
    ) -> DaemonRig {
        let dir = tempfile::tempdir().unwrap();
        let cfg = ServeConfig {
            link_dir: dir.path().to_owned(),
            daisy_chain: false,
            time_scale,
            control_socket: None,
            seed,
            ..ServeConfig::default()
        };
        let sim = serve(cfg).await;
        let socket = dir.path().join("d.sock");
        let data = dir.path().join("data");
        let mut c = DaemonConfig::default();
        c.daemon.socket = socket.clone();
        c.daemon.data_dir = data.clone();
        c.daemon.poll_interval_ms = 50;
        c.driver.x.port = sim.link(AxisName::X);
        c.driver.y.port = sim.link(AxisName::Y);
        for a in [&mut c.driver.x, &mut c.driver.y] {
            a.timeout_ms = 200;
            a.reference_timeout_s = 20.0;
            a.motion_timeout_s = 20.0;
        }
        c.driver.reconnect_min_ms = 20;
        c.driver.reconnect_max_ms = 200;
        tune(&mut c);
        c.validate().unwrap();
        let listener = tokio::net::UnixListener::bind(&socket).unwrap();
        let daemon = Daemon::start(c, Arc::new(WallClock::new()), None, listener).unwrap();
        DaemonRig {
            sim: Some(sim),
            daemon: Some(daemon),
            socket,
            data,
            served: true,
            dir,
        }
    }

    /// The rig in process (seed `seed`, `time_scale`) with the main job's
    /// daemon configuration for it (reduced plan), `tune` applied last;
    /// returns once both axes are connected and referenced.
    pub async fn in_process(
        seed: u64,
        time_scale: f64,
        tune: impl FnOnce(&mut DaemonConfig),
    ) -> DaemonRig {
        let InProcess {
            dir,
            data,
            socket,
            sim,
            rig: _,
            config: mut c,
        } = in_process_rig_at(seed, time_scale);
        tune(&mut c);
        c.validate().unwrap();
        let daemon = start_daemon_in_process(c, &sim, &socket);
        let r = DaemonRig {
            sim: Some(sim),
            daemon: Some(daemon),
            socket,
            data,
            served: false,
            dir,
        };
        let mut cl = Client::connect(&r.socket).await;
        connect_and_reference(&mut cl).await;
        r
    }

    /// The simulator (panics once it was taken).
    pub fn sim(&self) -> &SimHandle {
        self.sim.as_ref().unwrap()
    }

    /// The daemon (panics once it was taken).
    pub fn running(&self) -> &Running {
        self.daemon.as_ref().unwrap()
    }

    /// The platform's true position along `axis`, µm.
    pub fn truth_um(&self, axis: AxisName) -> f64 {
        self.sim().true_position_mm(axis) * 1000.0
    }

    /// Waits (up to `within`) until the daemon reports both controllers
    /// connected.
    pub async fn wait_connected(&self, within: Duration) {
        let mut cl = Client::connect(&self.socket).await;
        let t = Instant::now();
        loop {
            let s = cl.call(json!({"cmd": "status"})).await;
            if s["rig"]["connected"]["x"] == true && s["rig"]["connected"]["y"] == true {
                return;
            }
            assert!(t.elapsed() < within, "not connected: {s}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Stops the daemon, then the simulator (on a blocking thread).
    pub async fn shutdown(mut self) {
        if let Some(d) = self.daemon.take() {
            d.shutdown().await;
        }
        if let Some(s) = self.sim.take() {
            tokio::task::spawn_blocking(move || s.shutdown())
                .await
                .unwrap();
        }
    }
}
