//! `stop` latency on a busy line: from the moment a client's `stop` request
//! is written to the daemon's socket until both simulated controllers
//! report no motion, while four other clients keep both lines busy with
//! `position` (each a `POS?`/`FRF?` pair per axis), the daemon's poller runs
//! every 10 ms and the motion supervisor samples the moving axes.
//!
//! What it guards: `#24` is written ahead of the line's queue and during an
//! exchange's wait (`driver::line`, `Line::urgent`), so the latency stays
//! near one serial round of the line instead of growing with its queue.
//! Baseline in the same run: the same `stop` on a quiet line.
//!
//! The rig is served on ptys (`hil-sim serve` in process, simulated time at
//! 20× wall time) and the daemon runs in process on its own runtime, as in
//! `benches/daemon.rs`. Run: `cargo bench -p hil-sim --bench stop_latency`.

use criterion::{criterion_group, criterion_main, Criterion};
use hil_sim::{AxisName, ServeConfig, SimHandle};
use micropos::clock::WallClock;
use micropos::daemon::config::DaemonConfig;
use micropos::daemon::{Daemon, Running};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

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
    fn send(&mut self, mut req: Value) {
        self.next += 1;
        req["id"] = json!(self.next);
        self.w.write_all(format!("{req}\n").as_bytes()).unwrap();
    }
    fn reply(&mut self) -> Value {
        loop {
            let mut l = String::new();
            let n = self.r.read_line(&mut l).unwrap();
            assert!(n > 0, "connection closed");
            let v: Value = serde_json::from_str(&l).unwrap();
            if v.get("event").is_none() {
                assert_eq!(v["id"], json!(self.next), "{v}");
                return v;
            }
        }
    }
    fn call(&mut self, req: Value) -> Value {
        self.send(req);
        self.reply()
    }
}

struct BenchRig {
    sim: SimHandle,
    daemon: Running,
    socket: PathBuf,
    rt: tokio::runtime::Runtime,
    _dir: tempfile::TempDir,
}

fn start() -> BenchRig {
    let dir = tempfile::tempdir().unwrap();
    let sim = SimHandle::start(ServeConfig {
        link_dir: dir.path().to_owned(),
        daisy_chain: false,
        time_scale: 20.0,
        control_socket: None,
        seed: 11,
        ..ServeConfig::default()
    })
    .unwrap();
    let socket = dir.path().join("d.sock");
    let mut c = DaemonConfig::default();
    c.daemon.socket = socket.clone();
    c.daemon.data_dir = dir.path().join("data");
    c.daemon.poll_interval_ms = 10;
    c.driver.x.port = sim.link(AxisName::X);
    c.driver.y.port = sim.link(AxisName::Y);
    for a in [&mut c.driver.x, &mut c.driver.y] {
        a.reference_timeout_s = 60.0;
        a.motion_timeout_s = 60.0;
    }
    c.validate().unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let daemon = rt.block_on(async {
        let listener = tokio::net::UnixListener::bind(&socket).unwrap();
        Daemon::start(c, Arc::new(WallClock::new()), None, listener).unwrap()
    });
    let mut cl = Client::new(&socket);
    let t = Instant::now();
    loop {
        let s = cl.call(json!({"cmd":"status"}));
        if s["rig"]["connected"] == json!({"x": true, "y": true}) {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(20), "{s}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let rf = cl.call(json!({"cmd":"reference"}));
    assert_eq!(rf["ok"], true, "{rf}");
    BenchRig {
        sim,
        daemon,
        socket,
        rt,
        _dir: dir,
    }
}

fn moving(sim: &SimHandle) -> [bool; 2] {
    let m = |a| {
        sim.with_controller(a, |c, now| c.is_moving(now))
            .unwrap_or(false)
    };
    [m(AxisName::X), m(AxisName::Y)]
}

/// One stop: a long move of both axes, 30 ms later `stop`; the time from
/// writing the request until both controllers report rest.
fn one_stop(sim: &SimHandle, cl: &mut Client, far: bool) -> Duration {
    let (x, y) = if far {
        (14_000.0, 1_000.0)
    } else {
        (1_000.0, 14_000.0)
    };
    let m = cl.call(json!({"cmd":"move","x_um":x,"y_um":y}));
    assert_eq!(m["ok"], true, "{m}");
    let t = Instant::now();
    while moving(sim) != [true, true] {
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "the move did not start"
        );
    }
    std::thread::sleep(Duration::from_millis(30));
    let t0 = Instant::now();
    cl.send(json!({"cmd":"stop"}));
    while moving(sim) != [false, false] {
        assert!(t0.elapsed() < Duration::from_secs(10), "stop did not stop");
        std::hint::spin_loop();
    }
    let dt = t0.elapsed();
    let r = cl.reply();
    assert_eq!(r["ok"], true, "{r}");
    dt
}

fn bench(c: &mut Criterion) {
    let rig = start();
    let samples: Arc<Mutex<Vec<(bool, Duration)>>> = Arc::default();
    let mut group = c.benchmark_group("stop");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    for busy in [false, true] {
        let done = Arc::new(AtomicBool::new(false));
        let load: Vec<_> = (0..if busy { 4 } else { 0 })
            .map(|_| {
                let (p, done) = (rig.socket.clone(), done.clone());
                std::thread::spawn(move || {
                    let mut cl = Client::new(&p);
                    while !done.load(Ordering::Relaxed) {
                        let r = cl.call(json!({"cmd":"position"}));
                        assert_eq!(r["ok"], true, "{r}");
                    }
                })
            })
            .collect();
        let mut cl = Client::new(&rig.socket);
        let mut far = true;
        let name = if busy { "busy_line" } else { "quiet_line" };
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let dt = one_stop(&rig.sim, &mut cl, far);
                    far = !far;
                    samples.lock().unwrap().push((busy, dt));
                    total += dt;
                }
                total
            })
        });
        done.store(true, Ordering::Relaxed);
        for t in load {
            t.join().unwrap();
        }
    }
    group.finish();
    let s = samples.lock().unwrap();
    let mut p50 = [None, None];
    for busy in [false, true] {
        let mut v: Vec<f64> = s
            .iter()
            .filter(|(b, _)| *b == busy)
            .map(|(_, d)| d.as_secs_f64() * 1e3)
            .collect();
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            continue;
        }
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
        p50[usize::from(busy)] = Some(q(0.5));
        println!(
            "stop → both axes at rest, {} line: n {}, p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
            if busy { "busy" } else { "quiet" },
            v.len(),
            q(0.5),
            q(0.99),
            v[v.len() - 1]
        );
    }
    if let [Some(quiet), Some(busy)] = p50 {
        println!(
            "stop latency, busy / quiet line (p50, same run): {:.2}×",
            busy / quiet
        );
    }
    let BenchRig {
        sim, daemon, rt, ..
    } = rig;
    rt.block_on(daemon.shutdown());
    sim.shutdown();
}

criterion_group!(benches, bench);
criterion_main!(benches);
