//! The web view in a real browser: headless Chromium (Debian package
//! `chromium`) loads the page from microposd on a served simulated rig
//! (ptys, camera socket, scaled clock; free-running capture as on
//! hardware) at 1400 × 900 and the test reads the DOM over the DevTools
//! protocol, state by state, keeping a screenshot of each as
//! `target/artifacts/web-<state>.png`:
//!
//! - `idle`: at the `load` event the page already shows positions and a
//!   camera image that is not black (the state comes with the page); no
//!   fault panel; the page fits the screen (no page scrolling, the rig,
//!   camera and figures panels side by side, none too narrow);
//! - `moving`: while a move runs the page says the stage moves and the
//!   controller position changes; the camera image changes with the stage;
//! - `job-running`: a small characterization's progress bar and count
//!   advance while it runs, then reach done;
//! - `figures`: the job's Figs. 4–5 and a small validation's Fig. 10 are
//!   drawn from the `figures` command; every legend lies in its panel and
//!   off the plot area, bar value labels do not overlap one another and are
//!   rounded with their unit (also for a drawn example of many thin bars
//!   with the values a review found colliding);
//! - `fault`: a latched fault (a controller power cycle) shows the fault
//!   panel with the daemon's reason and the command that clears it.
//!
//! `chromium --headless --screenshot` of the page finishes (the event
//! stream starts only after `load`), and so does a screenshot with a
//! virtual-time budget of the still page (`?live=0`, no request open):
//! `web-headless.png`, `web-headless-still.png`. The page logs no console
//! error and throws no exception.
//!
//! Without Chromium the test is skipped with a printed reason, except
//! under `CI=true`, where it fails (`.ci/run` installs it).

use crate::common::{self, Client};
use hil_sim::run::{daemon_config, RunPlan};
use hil_sim::{AxisName, Fault};
use micropos::daemon::config::WebSection;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// The screen the page must fit, CSS px.
const SCREEN: (u32, u32) = (1400, 900);

/// Narrowest a main panel may be, CSS px: a positions table, a camera
/// image or a figure narrower than this is no longer readable.
const MIN_PANEL_PX: f64 = 280.0;

/// Flags every Chromium of this test runs with (root in a container: no
/// sandbox; no GPU, no /dev/shm needed).
const CHROMIUM_FLAGS: [&str; 7] = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--disable-background-networking",
];

/// Runs in every document before its own scripts: at the `load` event it
/// records what the page shows then (the camera canvas's mean brightness
/// and how often it was drawn, the controller position), so the test can
/// tell what a screenshot taken at `load` would show.
const AT_LOAD_PROBE: &str = r#"
window.addEventListener('load', () => {
  const c = document.getElementById('camera');
  let mean = 0;
  if (c && c.width && c.height) {
    const d = c.getContext('2d', { willReadFrequently: true }).getImageData(0, 0, c.width, c.height).data;
    let s = 0;
    for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
    mean = s / (3 * d.length / 4);
  }
  const x = document.getElementById('pos-controller-x');
  window.__atLoad = { mean, drawn: c ? Number(c.dataset.updates || 0) : 0, x: x ? x.textContent : null };
});
"#;

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
            .arg("--headless=new")
            .args(CHROMIUM_FLAGS)
            .args([
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--window-size={},{}", SCREEN.0, SCREEN.1))
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
        b.page(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": SCREEN.0, "height": SCREEN.1, "deviceScaleFactor": 1, "mobile": false}),
        );
        b.page(
            "Page.addScriptToEvaluateOnNewDocument",
            json!({"source": AT_LOAD_PROBE}),
        );
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

fn artifacts() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/artifacts")
}

/// The page's layout at the current state: it fits the screen (no page
/// scrolling either way) and the rig, camera and figures panels stand side
/// by side, each within the screen and at least [`MIN_PANEL_PX`] wide.
fn assert_fits_the_screen(b: &mut Browser, state: &str) {
    let v = b.eval(
        r#"(() => {
          const de = document.documentElement;
          const box = (id) => {
            const e = document.getElementById(id);
            if (!e) return null;
            const r = e.getBoundingClientRect();
            return [r.left, r.top, r.right, r.bottom];
          };
          return { w: innerWidth, h: innerHeight, sw: de.scrollWidth, sh: de.scrollHeight,
                   panels: [box('positions-panel'), box('camera-panel'), box('figures-panel')] };
        })()"#,
    );
    let (w, h) = (f64::from(SCREEN.0), f64::from(SCREEN.1));
    assert_eq!(
        (v["w"].as_f64(), v["h"].as_f64()),
        (Some(w), Some(h)),
        "{state}: viewport {v}"
    );
    assert!(
        v["sh"].as_f64().unwrap() <= h && v["sw"].as_f64().unwrap() <= w,
        "{state}: the page is {}×{} px, more than the {w}×{h} screen: it scrolls ({v})",
        v["sw"],
        v["sh"]
    );
    let panels: Vec<[f64; 4]> = v["panels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let p = p
                .as_array()
                .unwrap_or_else(|| panic!("{state}: a panel is missing: {v}"));
            [0, 1, 2, 3].map(|i| p[i].as_f64().unwrap())
        })
        .collect();
    for (name, [l, t, r, bt]) in ["positions", "camera", "figures"].iter().zip(&panels) {
        assert!(
            *l >= 0.0 && *r <= w && *t >= 0.0 && *t < h / 2.0 && *bt > *t,
            "{state}: the {name} panel is not on the screen's upper half: {v}"
        );
        assert!(
            r - l >= MIN_PANEL_PX,
            "{state}: the {name} panel is {} px wide (< {MIN_PANEL_PX}): {v}",
            r - l
        );
    }
    assert!(
        panels[0][2] <= panels[1][0] && panels[1][2] <= panels[2][0],
        "{state}: positions, camera and figures are not side by side: {v}"
    );
}

/// Checks the figures drawn in `container` (a CSS selector) and returns
/// what is wrong, one line each: every panel has a legend inside the
/// panel, off its plot area, with no two entries overlapping; bar value
/// labels are inside the panel, overlap neither one another nor the
/// legend, and read as a number of at most 3 decimals with its unit; no
/// numeric tick label is longer than 8 characters. `values_drawn`: bar
/// panels must show their value labels.
fn figure_problems(b: &mut Browser, container: &str, values_drawn: bool) -> Vec<String> {
    let v = b.eval(&format!(
        r#"(() => {{
          const problems = [];
          const box = (e) => e.getBoundingClientRect();
          const overlap = (a, b) => a.left < b.right - 0.5 && b.left < a.right - 0.5 &&
            a.top < b.bottom - 0.5 && b.top < a.bottom - 0.5;
          const inside = (a, b) => a.left >= b.left - 1 && a.right <= b.right + 1 &&
            a.top >= b.top - 1 && a.bottom <= b.bottom + 1;
          const panels = Array.from(document.querySelectorAll('{container} svg.fig-panel'));
          if (!panels.length) problems.push('no figure panel in {container}');
          panels.forEach((svg, i) => {{
            const title = svg.querySelector('.fig-title');
            const name = '{container} panel ' + i + ' (' + (title ? title.textContent : '?') + ')';
            const sb = box(svg);
            const plot = svg.querySelector('.fig-box');
            const legend = svg.querySelector('.fig-legend');
            if (!plot) problems.push(name + ': no plot area (.fig-box)');
            if (!legend) {{
              problems.push(name + ': no legend (.fig-legend)');
            }} else {{
              const lb = box(legend);
              if (!inside(lb, sb)) problems.push(name + ': legend leaves the panel ' + JSON.stringify([lb, sb]));
              if (plot && overlap(lb, box(plot))) problems.push(name + ': legend over the plot area');
              const items = Array.from(legend.querySelectorAll('text')).map(box);
              items.forEach((a, k) => items.slice(k + 1).forEach((c) => {{
                if (overlap(a, c)) problems.push(name + ': legend entries overlap');
              }}));
            }}
            const values = Array.from(svg.querySelectorAll('text.fig-value'));
            if (svg.dataset.kind === 'bars' && {values_drawn} && !values.length) problems.push(name + ': no value labels');
            const vb = values.map(box);
            values.forEach((t, k) => {{
              const s = t.textContent;
              if (!/^-?\d+(\.\d{{1,3}})? µm$/.test(s)) problems.push(name + ': value label ' + JSON.stringify(s) + ' is not rounded with its unit');
              if (!inside(vb[k], sb)) problems.push(name + ': value label ' + s + ' leaves the panel');
              if (legend && overlap(vb[k], box(legend))) problems.push(name + ': value label ' + s + ' over the legend');
              vb.slice(k + 1).forEach((c, j) => {{
                if (overlap(vb[k], c)) problems.push(name + ': value labels ' + s + ' and ' + values[k + 1 + j].textContent + ' overlap');
              }});
            }});
            svg.querySelectorAll('text.fig-tick').forEach((t) => {{
              const s = t.textContent;
              if (/^[-+.\deE]+$/.test(s) && s.length > 8) problems.push(name + ': tick label ' + s + ' not rounded');
            }});
          }});
          return problems;
        }})()"#
    ));
    v.as_array()
        .unwrap_or_else(|| panic!("figure check: {v}"))
        .iter()
        .map(|p| p.as_str().unwrap_or_default().to_owned())
        .collect()
}

/// A bar figure as the `figures` command sends it, with many modes: bars
/// too thin for labels across them, values of many digits (those a user
/// review found drawn as "0.1001240.0572587"), and a panel of 12 modes.
const CROWDED_BARS: &str = r#"(() => {
  const vals = [[26.9925, 0.100124, 0.0572587, 1.5], [15.6767, 0.0510548, 0.031968, 0.9], [0.696545, 0.0345066, 0.0572587, 0.3]];
  const names = ['AP, worst pose', 'AP, mean over poses', 'RP, worst pose'];
  const bars = (categories, value) => ({ kind: 'bars', title: 'summary per mode', categories, x_label: 'mode', y_label: 'µm',
    groups: vals.map((v, i) => ({ label: names[i], color: [0, 2, 3][i], values: categories.map((_, k) => value(v, k)) })) });
  const fig = { title: 'crowded bars', rows: [
    [bars(['raw', 'table', 'model', 'closed_loop'], (v, k) => v[k])],
    [bars(Array.from({ length: 12 }, (_, k) => 'mode ' + k), (v, k) => v[k % 4] * (1 + k / 7))]] };
  const d = document.createElement('div');
  d.id = 'crowded';
  document.getElementById('figures-panel').appendChild(d);
  return FIG.draw(d, [fig]);
})()"#;

/// Runs `chromium --headless --screenshot` of `url` with `extra` flags into
/// `to`; fails unless it finishes within `within` and writes a PNG of the
/// screen's size. A liveness check: the page must reach a state the
/// screenshot is taken in, not hold the browser forever.
fn headless_screenshot(bin: &Path, url: &str, extra: &[&str], to: &Path, within: Duration) {
    let profile = tempfile::tempdir().unwrap();
    let _ = std::fs::remove_file(to);
    let mut child = Command::new(bin)
        .arg("--headless")
        .args(CHROMIUM_FLAGS)
        .args(extra)
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", to.display()))
        .arg(format!("--window-size={},{}", SCREEN.0, SCREEN.1))
        .arg(url)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > within {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "chromium --headless --screenshot {extra:?} {url}: no screenshot within {within:?}"
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "chromium --screenshot {url}: {status}");
    let png = std::fs::read(to).unwrap();
    assert!(
        png.len() > 24 && png.starts_with(b"\x89PNG"),
        "{}",
        to.display()
    );
    let dim = |i: usize| u32::from_be_bytes([png[i], png[i + 1], png[i + 2], png[i + 3]]);
    assert_eq!((dim(16), dim(20)), SCREEN, "{}", to.display());
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
    cl.call_ok(json!({"cmd": "move", "x_um": 200.0, "y_um": 200.0, "wait": true}))
        .await;
    // The camera decodes the new position before the page is opened.
    tokio::time::sleep(Duration::from_millis(500)).await;

    // Idle: the page is complete at `load` (positions, a camera image),
    // shows no fault panel and fits the screen.
    let url = format!("http://{addr}/");
    let chrome = bin.clone();
    let mut b = tokio::task::spawn_blocking(move || {
        let mut b = Browser::launch(&chrome);
        b.page("Page.navigate", json!({"url": url}));
        b.wait_for(
            "the page loads",
            "document.readyState === 'complete' && window.__atLoad !== undefined",
            Duration::from_secs(30),
        );
        let at_load = b.eval("window.__atLoad");
        assert!(
            at_load["drawn"].as_f64() >= Some(1.0) && at_load["mean"].as_f64() > Some(10.0),
            "at load the camera image is not drawn or black: {at_load}"
        );
        assert!(
            (at_load["x"].as_str().unwrap_or("–").parse::<f64>().unwrap_or(f64::NAN) - 200.0).abs()
                < 0.5,
            "at load the controller position is not shown: {at_load}"
        );
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
            "the camera keeps drawing",
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
        assert_eq!(
            b.eval("(() => { const p = document.getElementById('fault-panel'); return !!p && p.hidden && p.getBoundingClientRect().height === 0; })()"),
            json!(true),
            "idle: a fault panel is shown"
        );
        assert_eq!(text(&mut b, "motion"), "at rest");
        assert_fits_the_screen(&mut b, "idle");
        b.screenshot(&artifacts().join("web-idle.png"));
        b
    })
    .await
    .unwrap();

    // Moving: a long move over the socket (not waited for; 11 mm, about
    // 2 s at the rig's ×5, ten controller polls) to where the camera sees
    // the pattern (vision ≈ (12 050, 12 100) µm − stage here). A recorder
    // in the page notes every controller position shown and what the page
    // said about motion at that moment.
    let hash0 =
        tokio::task::block_in_place(|| b.eval("document.getElementById('camera').dataset.hash"));
    let updates0 = tokio::task::block_in_place(|| {
        b.eval("Number(document.getElementById('positions').dataset.updates)")
    });
    tokio::task::block_in_place(|| {
        b.eval(
            "window.__motion = []; new MutationObserver(() => window.__motion.push([document.getElementById('pos-controller-x').textContent, document.getElementById('motion').textContent])).observe(document.getElementById('pos-controller-x'), { childList: true, characterData: true, subtree: true }); true",
        )
    });
    cl.call_ok(json!({"cmd": "move", "x_um": 8000.5, "y_um": 11000.25}))
        .await;
    tokio::task::block_in_place(|| {
        b.wait_for(
            "the page says the stage moves",
            "document.getElementById('motion').textContent === 'moving'",
            Duration::from_secs(30),
        );
        b.screenshot(&artifacts().join("web-moving.png"));
        assert_fits_the_screen(&mut b, "moving");
        b.wait_for(
            "the controller position follows the move",
            "Math.abs(Number(document.getElementById('pos-controller-x').textContent) - 8000.5) < 0.5 && Math.abs(Number(document.getElementById('pos-controller-y').textContent) - 11000.25) < 0.5",
            Duration::from_secs(30),
        );
        b.wait_for(
            "the page says the stage is at rest again",
            "document.getElementById('motion').textContent === 'at rest'",
            Duration::from_secs(30),
        );
        let seen = b.eval("window.__motion");
        let mut distinct: Vec<&str> = seen
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s[1] == "moving")
            .filter_map(|s| s[0].as_str())
            .collect();
        distinct.dedup();
        assert!(
            distinct.len() >= 3,
            "while moving the page showed {} controller positions: {seen}",
            distinct.len()
        );
        // The image changes, and once a frame of the stage at rest has been
        // drawn the overlay shows its decode (a frame grabbed during the
        // move may be too blurred to decode: "no decode", quality "–").
        b.wait_for(
            "the camera image changes and shows a decode",
            &format!("document.getElementById('camera').dataset.hash !== {hash0} && Number(document.getElementById('cam-quality').textContent) > 0"),
            Duration::from_secs(30),
        );
        let updates1 = b.eval("Number(document.getElementById('positions').dataset.updates)");
        assert!(
            updates1.as_f64() > updates0.as_f64(),
            "{updates0} → {updates1}"
        );
    });

    // Job running: a small job's progress advances on the page.
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
            "the job's progress advances while it runs",
            "document.getElementById('job-state').textContent === 'running' && document.getElementById('job-progress').value > 0",
            Duration::from_secs(60),
        );
        b.screenshot(&artifacts().join("web-job-running.png"));
        assert_fits_the_screen(&mut b, "job running");
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

    // Figures: a small validation's end draws Fig. 10 (plan view,
    // deviations, AP per pose on a log axis, AP/RP bars) and the AP/RP
    // table; legends and labels keep to their places.
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
        let mut problems = figure_problems(&mut b, "#charact-figures", true);
        problems.extend(figure_problems(&mut b, "#validation-figures", true));
        assert!(problems.is_empty(), "the figures: {problems:#?}");
        assert_fits_the_screen(&mut b, "figures");
        b.wait_for(
            "the page says the stage is at rest after the job",
            "document.getElementById('motion').textContent === 'at rest'",
            Duration::from_secs(30),
        );
        // The figures panel scrolled (inside itself) to the AP/RP bars.
        b.eval("document.querySelector('#validation-figures svg[data-kind=bars]').scrollIntoView({ block: 'end' }), true");
        b.screenshot(&artifacts().join("web-figures.png"));
        // The same drawing code on crowded bars: labels turn or stay out
        // rather than overlap.
        assert_eq!(b.eval(CROWDED_BARS), json!(2));
        let problems = figure_problems(&mut b, "#crowded", false);
        let turned = b.eval(
            "document.querySelectorAll('#crowded svg[data-kind=bars] text.fig-value').length",
        );
        b.eval("document.getElementById('crowded').remove(), true");
        assert!(problems.is_empty(), "crowded bars: {problems:#?}");
        assert!(
            turned.as_f64() >= Some(12.0),
            "the four-mode panel labels its 12 bars: {turned}"
        );
    });

    // Fault: a controller power cycle latches a fault; the page shows the
    // daemon's reason and what clears it.
    sim.inject(AxisName::Y, Fault::PowerCycle).unwrap();
    let reason = {
        let t = Instant::now();
        loop {
            let s = cl.call_ok(json!({"cmd": "status"})).await;
            if let Some(r) = s["rig"]["fault_latched"]["reason"].as_str() {
                break r.to_owned();
            }
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "no fault latched: {s}"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    };
    tokio::task::block_in_place(|| {
        b.wait_for(
            "the fault panel shows the latched fault",
            "(() => { const p = document.getElementById('fault-panel'); return !!p && !p.hidden && p.getBoundingClientRect().height > 0; })()",
            Duration::from_secs(30),
        );
        let shown = text(&mut b, "fault-latched");
        assert!(
            shown.contains(&reason),
            "{shown:?} lacks the reason {reason:?}"
        );
        let hint = text(&mut b, "fault-hint");
        assert!(
            hint.contains("micropos reset") && hint.contains(r#"{"cmd":"reset"}"#),
            "the fault panel does not say what clears the fault: {hint:?}"
        );
        assert_eq!(text(&mut b, "rig-mode"), "fault");
        // Both axes are halted; y reads no position any more (not
        // referenced), x alone still tells that the stage is at rest.
        b.wait_for(
            "the page says the halted stage is at rest",
            "document.getElementById('motion').textContent === 'at rest'",
            Duration::from_secs(30),
        );
        assert_fits_the_screen(&mut b, "fault");
        b.screenshot(&artifacts().join("web-fault.png"));
        assert!(
            b.errors.is_empty(),
            "the page logged errors: {:#?}",
            b.errors
        );
    });
    drop(b);

    // A plain headless screenshot finishes (nothing holds `load`), and so
    // does one that waits a virtual-time budget on the still page, which
    // keeps no request open.
    let base = format!("http://{addr}/");
    tokio::task::block_in_place(|| {
        headless_screenshot(
            &bin,
            &base,
            &[],
            &artifacts().join("web-headless.png"),
            Duration::from_secs(60),
        );
        headless_screenshot(
            &bin,
            &format!("{base}?live=0"),
            &["--virtual-time-budget=5000"],
            &artifacts().join("web-headless-still.png"),
            Duration::from_secs(60),
        );
    });
    daemon.shutdown().await;
    tokio::task::spawn_blocking(move || sim.shutdown())
        .await
        .unwrap();
}
