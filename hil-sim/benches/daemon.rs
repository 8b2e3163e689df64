//! microposd performance: `status` round trip over the Unix
//! socket, command-to-first-serial-byte latency of `move`, position stream
//! rate against the camera frame rate, CPU use of the idle daemon.
//!
//! The daemon runs in process against the in-process simulated rig (as
//! `tests/it/daemon_sim.rs`), on its own tokio runtime whose threads are named
//! `microposd-*` so its CPU time can be told apart from the simulator's and
//! the bench's (per-thread `/proc/self/task/*/stat`). Every figure is given
//! with a baseline measured in the same run, so the ratio says what the
//! daemon adds on this machine:
//!
//! * status RTT vs a bare line-echo server on the same kind of runtime;
//! * first serial byte of `move` (stamped by the simulator's line thread,
//!   `hil_sim::serve::RxProbe`) vs a bare pty write → read with the same
//!   poll loop on the far side;
//! * vision position events per second vs camera frames per second;
//! * idle CPU vs a runtime that only wakes at the daemon's poll interval.
//!
//! Criterion measures the medians of the two round trips; p50/p99 of every
//! latency come from the sample loops here and are printed at the end.
//! Run: `cargo bench -p hil-sim --bench daemon` (about two minutes).

use criterion::{criterion_group, criterion_main, Criterion};
use hil_sim::camera::SimCameraSource;
use hil_sim::{AxisName, ServeConfig, SimHandle};
use micropos::camera::{CameraError, CameraInfo, FrameSource};
use micropos::clock::WallClock;
use micropos::daemon::config::DaemonConfig;
use micropos::daemon::{Daemon, Running};
use micropos::frame::Frame;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Linux reports per-thread CPU in clock ticks of USER_HZ = 100 on every
/// architecture the kernel supports (`sysconf(_SC_CLK_TCK)`).
const TICKS_PER_S: f64 = 100.0;

/// A blocking line client of the daemon's socket protocol.
struct Client {
    r: BufReader<UnixStream>,
    w: UnixStream,
    next: u64,
}

impl Client {
    fn new(p: &Path) -> Client {
        let s = UnixStream::connect(p).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        Client {
            r: BufReader::new(s.try_clone().unwrap()),
            w: s,
            next: 0,
        }
    }
    fn line(&mut self) -> Value {
        let mut l = String::new();
        let n = self.r.read_line(&mut l).unwrap();
        assert!(n > 0, "connection closed");
        serde_json::from_str(&l).unwrap()
    }
    fn call(&mut self, mut req: Value) -> Value {
        self.next += 1;
        req["id"] = json!(self.next);
        self.w.write_all(format!("{req}\n").as_bytes()).unwrap();
        loop {
            let v = self.line();
            if v.get("event").is_none() {
                assert_eq!(v["id"], json!(self.next), "{v}");
                return v;
            }
        }
    }
}

/// The simulated camera, counting the frames the daemon takes.
#[derive(Debug)]
struct Counting {
    inner: SimCameraSource,
    frames: Arc<AtomicU64>,
}

impl FrameSource for Counting {
    fn info(&self) -> CameraInfo {
        self.inner.info()
    }
    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        let f = self.inner.next_frame()?;
        self.frames.fetch_add(1, Ordering::Relaxed);
        Ok(f)
    }
    fn set_timeout(&mut self, timeout: Duration) {
        self.inner.set_timeout(timeout)
    }
}

struct BenchRig {
    sim: Option<SimHandle>,
    daemon: Option<Running>,
    socket: PathBuf,
    frames: Arc<AtomicU64>,
    _dir: tempfile::TempDir,
}

fn runtime(name: &'static str) -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name(name)
        .enable_all()
        .build()
        .unwrap()
}

/// Simulated rig + daemon (default poll interval) on `rt`, referenced and
/// parked at (5000, 5000) µm, on the pattern. With the camera the clock
/// runs at real time (so its 30 frames per simulated second are 30 per wall
/// second) and referencing is fast-forwarded with `SimHandle::advance`;
/// without, the clock runs 20× (as `tests/it/daemon_sim.rs`).
fn start_rig(rt: &tokio::runtime::Runtime, camera: bool) -> BenchRig {
    let dir = tempfile::tempdir().unwrap();
    let cfg = ServeConfig {
        link_dir: dir.path().to_owned(),
        daisy_chain: false,
        time_scale: if camera { 1.0 } else { 20.0 },
        control_socket: None,
        seed: 11,
        ..ServeConfig::default()
    };
    let sim = SimHandle::start(cfg).unwrap();
    let socket = dir.path().join("d.sock");
    let mut c = DaemonConfig::default();
    c.daemon.socket = socket.clone();
    c.daemon.data_dir = dir.path().join("data");
    // The simulated camera's pattern (hil-sim default): 4 µm, 10-bit code.
    c.camera.period_um = 4.0;
    c.camera.bits = 10;
    c.driver.x.port = sim.link(AxisName::X);
    c.driver.y.port = sim.link(AxisName::Y);
    for a in [&mut c.driver.x, &mut c.driver.y] {
        a.reference_timeout_s = 60.0;
        a.motion_timeout_s = 60.0;
    }
    c.validate().unwrap();
    let frames = Arc::new(AtomicU64::new(0));
    let cam: Option<Box<dyn FrameSource>> = camera.then(|| {
        Box::new(Counting {
            inner: SimCameraSource::new(sim.camera().clone()),
            frames: frames.clone(),
        }) as Box<dyn FrameSource>
    });
    let daemon = rt.block_on(async {
        let listener = tokio::net::UnixListener::bind(&socket).unwrap();
        Daemon::start(c, Arc::new(WallClock::new()), cam, listener).unwrap()
    });
    let r = BenchRig {
        sim: Some(sim),
        daemon: Some(daemon),
        socket,
        frames,
        _dir: dir,
    };
    let mut cl = Client::new(&r.socket);
    let t = Instant::now();
    loop {
        let s = cl.call(json!({"cmd":"status"}));
        if s["rig"]["connected"]["x"] == true && s["rig"]["connected"]["y"] == true {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(20), "{s}");
        std::thread::sleep(Duration::from_millis(50));
    }
    let done = Arc::new(AtomicBool::new(false));
    std::thread::scope(|scope| {
        if camera {
            let (sim, done) = (r.sim.as_ref().unwrap(), done.clone());
            scope.spawn(move || {
                while !done.load(Ordering::Relaxed) {
                    sim.advance(Duration::from_millis(20));
                    std::thread::sleep(Duration::from_millis(2));
                }
            });
        }
        let rf = cl.call(json!({"cmd":"reference"}));
        assert_eq!(rf["ok"], true, "{rf}");
        let m = cl.call(json!({"cmd":"move","x_um":5000.0,"y_um":5000.0,"wait":true}));
        assert_eq!(m["ok"], true, "{m}");
        done.store(true, Ordering::Relaxed);
    });
    r
}

fn stop_rig(rt: &tokio::runtime::Runtime, mut r: BenchRig) {
    if let Some(d) = r.daemon.take() {
        rt.block_on(d.shutdown());
    }
    if let Some(s) = r.sim.take() {
        s.shutdown();
    }
}

/// A bare line-echo server on `rt`: the floor of any request/reply over a
/// Unix socket through tokio.
fn echo_server(rt: &tokio::runtime::Runtime, path: &Path) {
    use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
    let l = rt.block_on(async { tokio::net::UnixListener::bind(path).unwrap() });
    rt.spawn(async move {
        while let Ok((s, _)) = l.accept().await {
            tokio::spawn(async move {
                let (r, mut w) = s.into_split();
                let mut r = tokio::io::BufReader::new(r);
                let mut line = String::new();
                while r.read_line(&mut line).await.unwrap_or(0) > 0 {
                    if w.write_all(line.as_bytes()).await.is_err() {
                        return;
                    }
                    line.clear();
                }
            });
        }
    });
}

fn echo_rtt(r: &mut BufReader<UnixStream>, w: &mut UnixStream, msg: &[u8], buf: &mut String) {
    w.write_all(msg).unwrap();
    buf.clear();
    r.read_line(buf).unwrap();
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let i = ((p / 100.0) * (v.len() as f64 - 1.0)).round() as usize;
    v[i.min(v.len() - 1)]
}

struct Stats {
    p50_us: f64,
    p99_us: f64,
    n: usize,
}

fn stats(mut v: Vec<f64>) -> Stats {
    let n = v.len();
    Stats {
        p50_us: pct(&mut v, 50.0),
        p99_us: pct(&mut v, 99.0),
        n,
    }
}

/// CPU seconds used so far by this process's threads whose name starts
/// with `prefix`.
fn thread_cpu_s(prefix: &str) -> f64 {
    let mut ticks = 0u64;
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    for e in dir.flatten() {
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ...: comm may hold spaces; fields after the ')'.
        let (Some(a), Some(b)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        if !stat[a + 1..b].starts_with(prefix) {
            continue;
        }
        let f: Vec<&str> = stat[b + 1..].split_whitespace().collect();
        // After the comm: state is field 3, utime 14, stime 15 (1-based).
        let ut: u64 = f.get(11).and_then(|s| s.parse().ok()).unwrap_or(0);
        let st: u64 = f.get(12).and_then(|s| s.parse().ok()).unwrap_or(0);
        ticks += ut + st;
    }
    ticks as f64 / TICKS_PER_S
}

/// Baseline of the first-byte latency: a pty whose master is read by a
/// thread with the simulator's poll loop (5 ms poll timeout, wakes on
/// data); the bench writes a GCS move to the slave and the thread stamps
/// the arrival.
fn pty_baseline(n: usize) -> Vec<f64> {
    use nix::fcntl::OFlag;
    use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt};
    use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
    let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).unwrap();
    grantpt(&master).unwrap();
    unlockpt(&master).unwrap();
    let name = ptsname_r(&master).unwrap();
    let mut slave = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&name)
        .unwrap();
    let mut t = tcgetattr(slave.as_fd()).unwrap();
    cfmakeraw(&mut t);
    tcsetattr(slave.as_fd(), SetArg::TCSANOW, &t).unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<Instant>();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let mut master = master;
    let reader = std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while !stop2.load(Ordering::Relaxed) {
            let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
            if poll(&mut fds, PollTimeout::from(5u16)).unwrap_or(0) > 0 {
                if let Ok(k) = master.read(&mut buf) {
                    if k > 0 {
                        let _ = tx.send(Instant::now());
                    }
                }
            }
        }
    });
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        while rx.try_recv().is_ok() {}
        let t0 = Instant::now();
        slave
            .write_all(format!("MOV 1 {:.4}\n", 5.0 + 0.01 * (i % 2) as f64).as_bytes())
            .unwrap();
        if let Ok(t) = rx.recv_timeout(Duration::from_secs(1)) {
            out.push((t - t0).as_secs_f64() * 1e6);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    stop.store(true, Ordering::Relaxed);
    reader.join().unwrap();
    out
}

fn bench(c: &mut Criterion) {
    let tmp = tempfile::tempdir().unwrap();
    let rt = runtime("microposd-rt");
    let mut report = Vec::<String>::new();

    // --- Rig without camera: RTT, first byte, idle CPU -------------------
    let rig = start_rig(&rt, false);
    let mut cl = Client::new(&rig.socket);
    let status = json!({"cmd":"status"});
    c.bench_function("status_rtt", |b| b.iter(|| cl.call(status.clone())));
    let echo_path = tmp.path().join("echo.sock");
    echo_server(&rt, &echo_path);
    let mut ew = UnixStream::connect(&echo_path).unwrap();
    let mut er = BufReader::new(ew.try_clone().unwrap());
    let msg = format!("{}\n", json!({"id": 1, "cmd": "status"}));
    let mut buf = String::new();
    c.bench_function("unix_echo_rtt", |b| {
        b.iter(|| echo_rtt(&mut er, &mut ew, msg.as_bytes(), &mut buf))
    });

    let n = 2000;
    let mut s = Vec::with_capacity(n);
    let mut e = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        cl.call(status.clone());
        s.push(t.elapsed().as_secs_f64() * 1e6);
        let t = Instant::now();
        echo_rtt(&mut er, &mut ew, msg.as_bytes(), &mut buf);
        e.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let (s, e) = (stats(s), stats(e));
    report.push(format!(
        "status RTT            p50 {:8.1} µs  p99 {:8.1} µs  (n={})  | bare unix echo p50 {:6.1} µs p99 {:6.1} µs | ratio p50 {:.1}×, p99 {:.1}×",
        s.p50_us, s.p99_us, s.n, e.p50_us, e.p99_us, s.p50_us / e.p50_us, s.p99_us / e.p99_us
    ));

    // First serial byte of a move: arm the X line's probe, send the move,
    // read the stamp. Moves of 10 µm, waited for so each starts at rest.
    let probe = rig.sim.as_ref().unwrap().rx_probe(AxisName::X);
    let n = 150;
    let (mut first, mut mov) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n {
        let x = 5000.0 + 10.0 * ((i % 2) as f64);
        probe.arm(b"MOV");
        let t0 = Instant::now();
        let m = cl.call(json!({"cmd":"move","x_um":x,"wait":true}));
        assert_eq!(m["ok"], true, "{m}");
        let deadline = Instant::now() + Duration::from_secs(2);
        while probe.matched().is_none() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        if let (Some(f), Some(mv)) = (probe.first_byte(), probe.matched()) {
            first.push((f - t0).as_secs_f64() * 1e6);
            mov.push((mv - t0).as_secs_f64() * 1e6);
        }
    }
    let pty = stats(pty_baseline(500));
    let (first, mov) = (stats(first), stats(mov));
    report.push(format!(
        "move → first byte     p50 {:8.1} µs  p99 {:8.1} µs  (n={}); → chunk with MOV p50 {:.1} µs p99 {:.1} µs | bare pty write→read p50 {:.1} µs p99 {:.1} µs | ratio p50 {:.1}×",
        first.p50_us, first.p99_us, first.n, mov.p50_us, mov.p99_us, pty.p50_us, pty.p99_us, first.p50_us / pty.p50_us
    ));

    // Idle CPU: nothing asked for 10 s; the daemon polls both controllers
    // every poll_interval_ms (200 ms default).
    drop(cl);
    let idle_s = 10.0;
    let (c0, t0) = (thread_cpu_s("microposd"), Instant::now());
    std::thread::sleep(Duration::from_secs_f64(idle_s));
    let daemon_cpu = (thread_cpu_s("microposd") - c0) / t0.elapsed().as_secs_f64();
    stop_rig(&rt, rig);
    // Baseline: a runtime that only wakes at the same period.
    let base_rt = runtime("bare-timer-rt");
    base_rt.spawn(async {
        let mut iv = tokio::time::interval(Duration::from_millis(200));
        loop {
            iv.tick().await;
        }
    });
    let (b0, t0) = (thread_cpu_s("bare-timer"), Instant::now());
    std::thread::sleep(Duration::from_secs_f64(idle_s));
    let base_cpu = (thread_cpu_s("bare-timer") - b0) / t0.elapsed().as_secs_f64();
    drop(base_rt);
    report.push(format!(
        "idle CPU (no camera)  {:.3} % of one core over {idle_s} s | bare 200 ms timer runtime {:.3} % | difference {:.3} % (tick resolution 10 ms → ±{:.2} %)",
        100.0 * daemon_cpu,
        100.0 * base_cpu,
        100.0 * (daemon_cpu - base_cpu),
        100.0 * 0.01 / idle_s
    ));

    // --- Rig with camera: stream rate, CPU while streaming ----------------
    let rig = start_rig(&rt, true);
    let mut sub = Client::new(&rig.socket);
    let r = sub.call(json!({"cmd":"subscribe","topics":["position"]}));
    assert_eq!(r["ok"], true, "{r}");
    // Let the first frames decode.
    std::thread::sleep(Duration::from_secs(1));
    let span_s = 10.0;
    let f0 = rig.frames.load(Ordering::Relaxed);
    let c0 = thread_cpu_s("microposd");
    let t0 = Instant::now();
    let (mut vision, mut ctrl) = (0u64, 0u64);
    while t0.elapsed().as_secs_f64() < span_s {
        let v = sub.line();
        match v["source"].as_str() {
            Some("vision") => vision += 1,
            Some("controller") => ctrl += 1,
            _ => {}
        }
    }
    let el = t0.elapsed().as_secs_f64();
    let frames = rig.frames.load(Ordering::Relaxed) - f0;
    let cpu = (thread_cpu_s("microposd") - c0) / el;
    let (fps, vps) = (frames as f64 / el, vision as f64 / el);
    report.push(format!(
        "position stream       vision events {vps:.2}/s, controller events {:.2}/s | camera frames taken {fps:.2}/s | ratio stream/camera {:.3}",
        ctrl as f64 / el,
        vps / fps
    ));
    report.push(format!(
        "CPU with camera       {:.1} % of one core (capture + render of the simulated frame + decode + daemon)",
        100.0 * cpu
    ));
    drop(sub);
    stop_rig(&rt, rig);

    println!(
        "\n=== microposd performance (in-process daemon, in-process hil-sim rig; 20× clock without camera, 1× with) ==="
    );
    for l in &report {
        println!("{l}");
    }
    println!();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
