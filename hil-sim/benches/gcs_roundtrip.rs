//! Round-trip time of GCS exchanges over a pty to the simulated C-863:
//! through the micropos driver (line task + session + controller) versus a
//! bare blocking write/read loop on the same pty, in the same run. The ratio
//! of medians is the driver's overhead.
//!
//! Run: `cargo bench -p hil-sim --bench gcs_roundtrip`. Besides criterion's
//! report it prints a median table at the end.

use criterion::{criterion_group, Criterion};
use hil_sim::serve::read_answer;
use hil_sim::{AxisName, ServeConfig, SimHandle};
use micropos::driver::{Axis, Controller, DriverConfig, Stage};
use micropos::gcs::{AxisId, Command};
use std::fs::File;
use std::io::Write;
use std::time::{Duration, Instant};
use tokio::runtime::Runtime;
use tokio::sync::broadcast;

const TIMEOUT: Duration = Duration::from_secs(1);

struct Bench {
    _dir: tempfile::TempDir,
    sim: SimHandle,
    rt: Runtime,
}

fn setup() -> Bench {
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = SimHandle::start(ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.path().to_owned(),
        time_scale: 20.0,
        seed: 1,
        ..ServeConfig::default()
    })
    .expect("start hil-sim");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    // Reference X once (so MOV is accepted), then close the driver.
    rt.block_on(async {
        let (x, _) = connect(&sim).await;
        x.reference().await.expect("reference");
    });
    Bench { _dir: dir, sim, rt }
}

async fn connect(sim: &SimHandle) -> (Axis, Controller) {
    let mut cfg = DriverConfig::default();
    cfg.x.port = sim.link(AxisName::X);
    cfg.y.port = sim.link(AxisName::Y);
    let (tx, _) = broadcast::channel(16);
    let stage = Stage::connect(&cfg, tx).await.expect("driver connect");
    let ctl = stage.x.controller().clone();
    (stage.x, ctl)
}

fn pos() -> Command {
    Command::PosQuery(vec![AxisId::new("1").expect("axis id")])
}

fn mov(i: u64) -> Command {
    let t = if i % 2 == 0 { 5.0 } else { 5.0001 };
    Command::Mov(vec![(AxisId::new("1").expect("axis id"), t)])
}

fn open_bare(b: &Bench) -> File {
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(b.sim.link(AxisName::X))
        .expect("open pty")
}

fn bare_pos(f: &mut File) {
    f.write_all(b"POS? 1\n").expect("write");
    let a = read_answer(f, TIMEOUT).expect("answer");
    assert!(a.starts_with(b"1="));
}

fn bare_mov_err(f: &mut File, i: u64) {
    let line = if i % 2 == 0 {
        "MOV 1 5\n"
    } else {
        "MOV 1 5.0001\n"
    };
    f.write_all(line.as_bytes()).expect("write");
    f.write_all(b"ERR?\n").expect("write");
    let a = read_answer(f, TIMEOUT).expect("answer");
    assert_eq!(a, b"0\n");
}

fn benches(c: &mut Criterion) {
    let b = setup();
    let mut g = c.benchmark_group("gcs_roundtrip");
    g.sample_size(50)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_millis(500));
    {
        // The bare loop runs while no driver holds the (exclusive) port.
        let mut f = open_bare(&b);
        g.bench_function("bare POS?", |bn| bn.iter(|| bare_pos(&mut f)));
        let mut i = 0;
        g.bench_function("bare MOV+ERR?", |bn| {
            bn.iter(|| {
                i += 1;
                bare_mov_err(&mut f, i)
            })
        });
    }
    {
        let (_x, ctl) = b.rt.block_on(connect(&b.sim));
        let p = pos();
        g.bench_function("driver POS?", |bn| {
            bn.iter(|| b.rt.block_on(ctl.query(&p)).expect("POS?"))
        });
        let mut i = 0;
        g.bench_function("driver MOV+ERR?", |bn| {
            bn.iter(|| {
                i += 1;
                b.rt.block_on(ctl.set(&mov(i))).expect("MOV")
            })
        });
    }
    g.finish();
    summary(&b);
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn time_n(n: u64, mut f: impl FnMut(u64)) -> Duration {
    let mut v = Vec::new();
    for i in 0..n {
        let t = Instant::now();
        f(i);
        v.push(t.elapsed());
    }
    median(v)
}

/// Medians of interleaved rounds, and the driver/bare ratios.
fn summary(b: &Bench) {
    const N: u64 = 300;
    let (bare_pos_t, bare_mov_t) = {
        let mut f = open_bare(b);
        (
            time_n(N, |_| bare_pos(&mut f)),
            time_n(N, |i| bare_mov_err(&mut f, i)),
        )
    };
    let (x, ctl) = b.rt.block_on(connect(&b.sim));
    let p = pos();
    let drv_pos_t = time_n(N, |_| {
        b.rt.block_on(ctl.query(&p)).expect("POS?");
    });
    let drv_mov_t = time_n(N, |i| {
        b.rt.block_on(ctl.set(&mov(i))).expect("MOV");
    });
    let drv_position_um_t = time_n(N, |_| {
        b.rt.block_on(x.position_um()).expect("position");
    });
    let ratio = |d: Duration, bare: Duration| d.as_secs_f64() / bare.as_secs_f64();
    println!("\nmedian round trips over a pty to hil-sim ({N} each):");
    println!(
        "  POS?            bare {bare_pos_t:>10.1?}  driver {drv_pos_t:>10.1?}  ratio {:.2}",
        ratio(drv_pos_t, bare_pos_t)
    );
    println!(
        "  MOV + ERR?      bare {bare_mov_t:>10.1?}  driver {drv_mov_t:>10.1?}  ratio {:.2}",
        ratio(drv_mov_t, bare_mov_t)
    );
    println!("  position_um()   (POS? + FRF?, checked)      {drv_position_um_t:>10.1?}");
}

criterion_group!(gcs, benches);

fn main() {
    gcs();
    Criterion::default().configure_from_args().final_summary();
}
