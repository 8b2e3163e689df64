//! The web view in a real browser: headless Chromium (Debian package
//! `chromium`) loads the page from microposd on a served simulated rig
//! (ptys, camera socket, scaled clock; free-running capture as on
//! hardware) and the test reads the DOM over the DevTools protocol:
//! positions update after a move sent over the socket, the camera image
//! changes when the stage moves, a small job's progress advances, the
//! figures panel says "no characterization yet" before it and draws the
//! job's Figs. 4–5 (from the `figures` command) after it, a small
//! validation's end draws Fig. 10 with its AP/RP table, and the page logs
//! no console error and throws no exception. Screenshots are kept as
//! `target/artifacts/web-view.png` (the top of the page) and
//! `web-figures.png` (the validation figures).
//!
//! Without Chromium the test is skipped with a printed reason, except
//! under `CI=true`, where it fails (`.ci/run` installs it).

use crate::common::{self, Client};
use hil_sim::run::{daemon_config, RunPlan};
use micropos::daemon::config::WebSection;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// The browser: `$CHROME`, else `chromium` on PATH.
fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("CHROME") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|n| std::env::split_paths(&path).map(move |d| d.join(n)))
        .find(|p| p.is_file())
}

/// A DevTools-protocol session with one page of a headless Chromium.
struct Browser {
    child: Child,
    ws: WebSocket<MaybeTlsStream<TcpStream>>,
    session: String,
    next_id: u64,
    /// Console errors, exceptions and error log entries seen so far.
    errors: Vec<String>,
    _profile: tempfile::TempDir,
}

impl Browser {
    fn launch(bin: &Path) -> Browser {
        let profile = tempfile::tempdir().unwrap();
        let mut child = Command::new(bin)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-extensions",
                "--disable-background-networking",
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
                "--window-size=1400,1100",
            ])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("chromium starts");
        // Chromium prints its DevTools endpoint on stderr.
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(url) = line.split("DevTools listening on ").nth(1) {
                    let _ = tx.send(url.trim().to_owned());
                }
            }
        });
        let url = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("chromium printed its DevTools address");
        let (ws, _) = tungstenite::connect(url.as_str()).expect("DevTools websocket");
        if let MaybeTlsStream::Plain(s) = ws.get_ref() {
            s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        }
        let mut b = Browser {
            child,
            ws,
            session: String::new(),
            next_id: 0,
            errors: Vec::new(),
            _profile: profile,
        };
        let t = b.call(None, "Target.createTarget", json!({"url": "about:blank"}));
        let target = t["targetId"].as_str().unwrap().to_owned();
        let s = b.call(
            None,
            "Target.attachToTarget",
            json!({"targetId": target, "flatten": true}),
        );
        b.session = s["sessionId"].as_str().unwrap().to_owned();
        for domain in ["Runtime.enable", "Log.enable", "Page.enable"] {
            b.page(domain, json!({}));
        }
        b
    }

    /// Sends one command and returns its result; events read meanwhile
    /// are checked for errors.
    fn call(&mut self, session: Option<&str>, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if let Some(s) = session {
            msg["sessionId"] = json!(s);
        }
        self.ws
            .send(Message::text(msg.to_string()))
            .expect("DevTools send");
        loop {
            let m = self.ws.read().expect("DevTools answer");
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(t.as_str()).unwrap();
            if v["id"] == json!(id) {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
            self.note_event(&v);
        }
    }

    fn page(&mut self, method: &str, params: Value) -> Value {
        let s = self.session.clone();
        self.call(Some(&s), method, params)
    }

    fn note_event(&mut self, v: &Value) {
        let p = &v["params"];
        match v["method"].as_str() {
            Some("Runtime.exceptionThrown") => self
                .errors
                .push(format!("exception: {}", p["exceptionDetails"])),
            Some("Runtime.consoleAPICalled") if p["type"] == "error" || p["type"] == "assert" => {
                self.errors
                    .push(format!("console.{}: {}", p["type"], p["args"]))
            }
            Some("Log.entryAdded") if p["entry"]["level"] == "error" => {
                self.errors.push(format!("log: {}", p["entry"]))
            }
            _ => {}
        }
    }

    /// Evaluates `expr` in the page and returns its value.
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.page(
            "Runtime.evaluate",
            json!({"expression": expr, "returnByValue": true}),
        );
        assert!(r.get("exceptionDetails").is_none(), "{expr}: {r}");
        r["result"]["value"].clone()
    }

    /// Polls `expr` until it is `true` (fails after `within`); an
    /// exception (the page still loading) counts as not yet.
    fn wait_for(&mut self, what: &str, expr: &str, within: Duration) {
        let t = Instant::now();
        let guarded =
            format!("(() => {{ try {{ return ({expr}); }} catch (e) {{ return false; }} }})()");
        loop {
            if self.eval(&guarded) == json!(true) {
                return;
            }
            assert!(
                t.elapsed() < within,
                "{what}: not within {within:?}; page state: {}",
                self.eval("document.body ? document.body.innerText : ''")
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    fn screenshot(&mut self, to: &Path) {
        use base64::Engine as _;
        let r = self.page("Page.captureScreenshot", json!({"format": "png"}));
        let png = base64::engine::general_purpose::STANDARD
            .decode(r["data"].as_str().unwrap())
            .unwrap();
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::write(to, png).unwrap();
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn text(b: &mut Browser, id: &str) -> String {
    b.eval(&format!("document.getElementById('{id}').textContent"))
        .as_str()
        .unwrap_or_default()
        .to_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_live_rig() {
    let Some(bin) = chromium() else {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI must run the browser test: install the Debian package chromium"
        );
        eprintln!("SKIPPED: no chromium (Debian package `chromium`, or set CHROME)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    let cfg = common::serve_config(&rig_dir, 5.0, 21);
    let rig_cfg = cfg.rig.clone();
    let sim = common::serve(cfg).await;
    let socket = dir.path().join("d.sock");
    let mut c = daemon_config(&rig_dir, &data, &socket, &rig_cfg, &RunPlan::reduced()).unwrap();
    c.web = Some(WebSection {
        listen: "127.0.0.1:0".to_owned(),
        ..WebSection::default()
    });
    c.validate().unwrap();
    let daemon = common::start_daemon(c, rig_dir.join("control.sock"), &socket).await;
    let addr = daemon.web_addr.expect("the web listener is bound");
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;
    cl.call_ok(json!({"cmd": "move", "x_um": 200.0, "y_um": 200.0}))
        .await;

    let url = format!("http://{addr}/");
    let mut b = tokio::task::spawn_blocking(move || {
        let mut b = Browser::launch(&bin);
        b.page("Page.navigate", json!({"url": url}));
        b.wait_for(
            "the event stream connects",
            "document.getElementById('conn').textContent === 'live'",
            Duration::from_secs(30),
        );
        b.wait_for(
            "positions arrive",
            "Number(document.getElementById('positions').dataset.updates) > 0 && document.getElementById('pos-controller-x').textContent !== '–'",
            Duration::from_secs(30),
        );
        b.wait_for(
            "a camera image is drawn",
            "Number(document.getElementById('camera').dataset.updates) > 0",
            Duration::from_secs(30),
        );
        // No log yet: the figures panel says so (the `figures` error reply).
        b.wait_for(
            "the figures panel says there is no characterization yet",
            "document.getElementById('charact-status').textContent.startsWith('no characterization yet')",
            Duration::from_secs(30),
        );
        assert_eq!(
            b.eval("document.querySelectorAll('#charact-figures svg').length"),
            json!(0)
        );
        b
    })
    .await
    .unwrap();

    // A move over the socket: the controller position and the camera
    // image follow.
    let hash0 =
        tokio::task::block_in_place(|| b.eval("document.getElementById('camera').dataset.hash"));
    let updates0 = tokio::task::block_in_place(|| {
        b.eval("Number(document.getElementById('positions').dataset.updates)")
    });
    cl.call_ok(json!({"cmd": "move", "x_um": 1234.5, "y_um": 987.25}))
        .await;
    tokio::task::block_in_place(|| {
        b.wait_for(
            "the controller position follows the move",
            "Math.abs(Number(document.getElementById('pos-controller-x').textContent) - 1234.5) < 0.5 && Math.abs(Number(document.getElementById('pos-controller-y').textContent) - 987.25) < 0.5",
            Duration::from_secs(30),
        );
        b.wait_for(
            "the camera image changes",
            &format!("document.getElementById('camera').dataset.hash !== {hash0}"),
            Duration::from_secs(30),
        );
        let updates1 = b.eval("Number(document.getElementById('positions').dataset.updates)");
        assert!(
            updates1.as_f64() > updates0.as_f64(),
            "{updates0} → {updates1}"
        );
        // The overlay shows the decode of the new position.
        let q: f64 = text(&mut b, "cam-quality").parse().unwrap_or(0.0);
        assert!(q > 0.0, "decode quality shown: {q}");
    });

    // A small job: its progress advances on the page.
    cl.call_ok(
        json!({"cmd": "characterize", "action": "start", "log": "web.csv", "axes": "x",
           "step_um": 200.0, "x_range_um": 600.0, "y_range_um": 400.0, "cycles": 1,
           "frames_per_point": 1, "settle_s": 0.05, "drift_every_s": 0.0}),
    )
    .await;
    tokio::task::block_in_place(|| {
        b.wait_for(
            "the job shows as running with points planned",
            "Number(document.getElementById('job-total').textContent) > 0",
            Duration::from_secs(30),
        );
        b.wait_for(
            "the job's progress advances",
            "document.getElementById('job-progress').value > 0",
            Duration::from_secs(60),
        );
        b.wait_for(
            "the job ends",
            "document.getElementById('job-state').textContent === 'done'",
            Duration::from_secs(90),
        );
        let done = text(&mut b, "job-done");
        let total = text(&mut b, "job-total");
        assert_eq!(done, total);
        // The job's end redraws the figures panel from `figures`: the
        // paper's Figs. 4 and 5 of web.csv (one cycle: no Fig. 6), every
        // panel with marks, and the summary row of the x scan.
        b.wait_for(
            "the characterization figures are drawn",
            "document.getElementById('charact-figures').dataset.drawn === 'web.csv'",
            Duration::from_secs(30),
        );
        let panels = b.eval(
            "Array.from(document.querySelectorAll('#charact-figures svg.fig-panel')).map((s) => Number(s.dataset.marks))",
        );
        let marks: Vec<f64> = panels
            .as_array()
            .unwrap()
            .iter()
            .filter_map(Value::as_f64)
            .collect();
        assert_eq!(marks.len(), 2, "Figs. 4 and 5, one panel each: {panels}");
        assert!(marks.iter().all(|&m| m > 0.0), "{panels}");
        assert_eq!(
            b.eval("document.querySelector('#charact-table tbody td').textContent"),
            json!("x")
        );
        assert!(text(&mut b, "charact-status").starts_with("web.csv"));
        assert!(text(&mut b, "validation-status").starts_with("no validation yet"));
    });

    // A small validation: its end draws Fig. 10 (plan view, deviations, AP
    // per pose on a log axis, AP/RP bars) and the AP/RP table.
    cl.call_ok(
        json!({"cmd": "validate", "action": "start", "test": "square", "modes": ["raw"],
           "cycles": 2, "square_step_um": 4000.0, "origin_x_um": 100.0, "origin_y_um": 100.0,
           "frames_per_point": 1, "settle_s": 0.05, "log": "web-val.csv"}),
    )
    .await;
    tokio::task::block_in_place(|| {
        b.wait_for(
            "the validation figures are drawn",
            "document.getElementById('validation-figures').dataset.drawn === 'web-val.csv'",
            Duration::from_secs(120),
        );
        let kinds = b.eval(
            "Array.from(document.querySelectorAll('#validation-figures svg.fig-panel')).map((s) => s.dataset.kind + ':' + s.dataset.marks)",
        );
        let kinds: Vec<String> = kinds
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|v| v.as_str().map(str::to_owned))
            .collect();
        assert!(kinds.len() >= 3, "{kinds:?}");
        assert!(kinds.iter().any(|k| k.starts_with("bars:")), "{kinds:?}");
        assert!(
            kinds.iter().all(|k| !k.ends_with(":0")),
            "every panel has marks: {kinds:?}"
        );
        assert_eq!(
            b.eval("document.querySelector('#validation-table tbody td:nth-child(2)').textContent"),
            json!("raw")
        );
        let artifacts = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/artifacts");
        b.screenshot(&artifacts.join("web-view.png"));
        b.eval("document.getElementById('validation-figures').scrollIntoView(), true");
        b.screenshot(&artifacts.join("web-figures.png"));
        assert!(
            b.errors.is_empty(),
            "the page logged errors: {:#?}",
            b.errors
        );
    });
    drop(b);
    daemon.shutdown().await;
    tokio::task::spawn_blocking(move || sim.shutdown())
        .await
        .unwrap();
}
