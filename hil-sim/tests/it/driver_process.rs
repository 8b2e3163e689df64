//! The driver against the `hil-sim` binary running as a separate process:
//! the same serial path a real deployment uses, with faults injected through
//! the JSON-lines control socket.

use micropos::driver::{AxisEvent, DriverConfig, DriverError, Stage};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

struct Sim {
    child: Child,
    x: PathBuf,
    y: PathBuf,
    control: PathBuf,
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start(dir: &Path) -> Sim {
    let control = dir.join("control.sock");
    let mut child = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["serve", "--link-dir"])
        .arg(dir)
        .args(["--time-scale", "20", "--seed", "3", "--control"])
        .arg(&control)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    // "hil-sim ready x=DIR/x y=DIR/y"
    let mut words = line.split_whitespace();
    assert_eq!(words.next(), Some("hil-sim"));
    assert_eq!(words.next(), Some("ready"));
    let x = words.next().unwrap().strip_prefix("x=").unwrap().into();
    let y = words.next().unwrap().strip_prefix("y=").unwrap().into();
    Sim {
        child,
        x,
        y,
        control,
    }
}

fn control(sim: &Sim, request: &str) -> String {
    let mut s = UnixStream::connect(&sim.control).unwrap();
    writeln!(s, "{request}").unwrap();
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply).unwrap();
    assert!(reply.contains("\"ok\":true"), "{request} -> {reply}");
    reply
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn driver_against_the_hil_sim_process() {
    let dir = tempfile::tempdir().unwrap();
    let sim = start(dir.path());
    let mut cfg = DriverConfig::default();
    cfg.x.port = sim.x.clone();
    cfg.y.port = sim.y.clone();
    for a in [&mut cfg.x, &mut cfg.y] {
        a.timeout_ms = 300;
    }
    cfg.reconnect_min_ms = 20;
    let (tx, mut rx) = broadcast::channel(256);
    let stage = Stage::connect(&cfg, tx).await.unwrap();
    let (x, y) = tokio::join!(stage.x.reference(), stage.y.reference());
    x.unwrap();
    y.unwrap();
    let (a, b) = tokio::join!(stage.x.move_abs_um(2_500.0), stage.y.move_abs_um(11_000.0));
    a.unwrap();
    b.unwrap();
    let (px, py) = tokio::join!(stage.x.wait_on_target(None), stage.y.wait_on_target(None));
    assert!((px.unwrap() - 2_500.0).abs() < 0.5);
    assert!((py.unwrap() - 11_000.0).abs() < 0.5);
    let truth = control(&sim, r#"{"query":"truth"}"#);
    assert!(truth.contains("\"x_mm\":2.5"), "{truth}");

    // Power cycle through the control socket: positions refused.
    control(&sim, r#"{"axis":"x","fault":"power_cycle"}"#);
    assert!(matches!(
        stage.x.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    // Pulled cable on y, then back.
    control(&sim, r#"{"axis":"y","fault":"drop_line"}"#);
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(matches!(
        stage.y.position_um().await,
        Err(DriverError::Disconnected { .. })
    ));
    control(&sim, r#"{"axis":"y","fault":"restore_line"}"#);
    let start = Instant::now();
    let p = loop {
        match stage.y.position_um().await {
            Ok(p) => break p,
            Err(e) if start.elapsed() < Duration::from_secs(5) => {
                assert!(e.is_link_fault(), "{e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            Err(e) => panic!("{e}"),
        }
    };
    assert!((p - 11_000.0).abs() < 0.5);
    let mut events = Vec::new();
    while let Ok(e) = rx.try_recv() {
        events.push(e);
    }
    assert!(events.contains(&AxisEvent::ReferenceLost { axis: "x".into() }));
    assert!(events
        .iter()
        .any(|e| matches!(e, AxisEvent::Disconnected { .. })));

    // The simulator exits on SIGTERM and removes its links.
    let pid = sim.child.id().to_string();
    let st = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    assert!(st.success());
    let mut sim = sim;
    let status = sim.child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    assert!(!sim.x.exists() && !sim.y.exists());
    // And the driver says the line is gone.
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(matches!(
        stage.x.is_referenced().await,
        Err(DriverError::Disconnected { .. })
    ));
}
