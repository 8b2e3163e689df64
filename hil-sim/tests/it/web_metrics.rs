//! The web listener on microposd with the in-process simulated rig (paused
//! clock): `GET /metrics` parses as Prometheus text and its values move
//! with activity (moves, a refused move's error code, frames decoded,
//! decode times, job progress); `POST /api/command` runs the socket's
//! commands with the socket's rules (anonymous reads only, the token for
//! anything else, the role, the audit trail); `GET /api/events` streams
//! the event bus; the page and its script are served. Also: `figures`
//! over both paths against the logs' own analysis, the sign of
//! `micropos_vision_residual_um`, and the listener's connection cap and
//! idle timeout.

use crate::common::{self, http, Client};
use hil_sim::{AxisName, Fault};
use micropos::daemon::config::WebSection;
use prometheus_parse::{Scrape, Value as PValue};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::net::SocketAddr;

const TOKEN: &str = "test-token-5d41402abc4b2a76b9719d911017c592";

/// A served rig (seed `seed`, time scale 50) and an in-process daemon on the
/// reduced plan whose web listener (`web`, on an ephemeral loopback port)
/// is bound. `_dir` holds the rig's and the data's directory.
struct WebRig {
    _dir: tempfile::TempDir,
    data: std::path::PathBuf,
    socket: std::path::PathBuf,
    sim: hil_sim::SimHandle,
    daemon: micropos::daemon::Running,
    addr: SocketAddr,
}

/// `[web]` with control on, role operate and the test token.
fn operate_with_token() -> WebSection {
    WebSection {
        control: true,
        role: "operate".to_owned(),
        token: Some(TOKEN.to_owned()),
        ..WebSection::default()
    }
}

fn web_rig(seed: u64, web: WebSection) -> WebRig {
    let common::InProcess {
        dir,
        data,
        socket,
        sim,
        rig: _,
        config: mut c,
    } = common::in_process_rig(seed);
    c.web = Some(WebSection {
        listen: "127.0.0.1:0".to_owned(),
        ..web
    });
    c.validate().unwrap();
    let daemon = common::start_daemon_in_process(c, &sim, &socket);
    let addr = daemon.web_addr.expect("the web listener is bound");
    WebRig {
        _dir: dir,
        data,
        socket,
        sim,
        daemon,
        addr,
    }
}

/// Parses a scrape; samples by name with their labels joined
/// (`name{k=v,…}`), histograms by name with their count.
fn scrape(text: &str) -> HashMap<String, f64> {
    let lines = text.lines().map(|l| Ok(l.to_owned()));
    let s = Scrape::parse(lines).expect("a Prometheus text scrape");
    let mut out = HashMap::new();
    for sample in s.samples {
        let mut labels: Vec<String> = sample
            .labels
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        labels.sort();
        let key = if labels.is_empty() {
            sample.metric.clone()
        } else {
            format!("{}{{{}}}", sample.metric, labels.join(","))
        };
        let v = match sample.value {
            PValue::Counter(v) | PValue::Gauge(v) | PValue::Untyped(v) => v,
            PValue::Histogram(h) => h.iter().map(|b| b.count).fold(0.0, f64::max),
            PValue::Summary(_) => continue,
        };
        out.insert(key, v);
    }
    out
}

async fn metrics(addr: SocketAddr) -> HashMap<String, f64> {
    let (status, head, body) = http(addr, "GET", "/metrics", &[], b"").await;
    assert_eq!(status, 200);
    assert!(
        head.contains("content-type: application/openmetrics-text"),
        "{head}"
    );
    let text = String::from_utf8(body).unwrap();
    assert!(text.ends_with("# EOF\n"), "{text}");
    scrape(&text)
}

fn get(m: &HashMap<String, f64>, k: &str) -> f64 {
    *m.get(k)
        .unwrap_or_else(|| panic!("{k} not in the scrape: {m:?}"))
}

async fn command(addr: SocketAddr, req: Value, token: Option<&str>) -> (u16, Value) {
    let auth = token.map(|t| format!("Bearer {t}"));
    let mut headers = vec![("Content-Type", "application/json")];
    if let Some(a) = &auth {
        headers.push(("Authorization", a.as_str()));
    }
    let (status, _, body) = http(
        addr,
        "POST",
        "/api/command",
        &headers,
        req.to_string().as_bytes(),
    )
    .await;
    (status, serde_json::from_slice(&body).unwrap())
}

/// Reads `GET /api/events` until every one of `wanted` has appeared.
async fn sse_until(addr: SocketAddr, wanted: &[&str]) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut text = String::new();
    let mut chunk = [0u8; 4096];
    while !wanted.iter().all(|w| text.contains(w)) {
        let n = tokio::time::timeout(std::time::Duration::from_secs(60), s.read(&mut chunk))
            .await
            .expect("events within a minute")
            .unwrap();
        assert!(n > 0, "the stream ended: {text}");
        text.push_str(&String::from_utf8_lossy(&chunk[..n]));
    }
    text
}

#[tokio::test(start_paused = true)]
async fn metrics_and_commands_follow_the_rig() {
    let WebRig {
        _dir,
        data,
        socket,
        sim,
        daemon,
        addr,
    } = web_rig(3, operate_with_token());
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;

    // The page and its script are served, with a content security policy.
    let (status, head, body) = http(addr, "GET", "/", &[], b"").await;
    assert_eq!(status, 200);
    assert!(head.contains("content-security-policy"), "{head}");
    assert!(String::from_utf8_lossy(&body).contains("/app.js"));
    let (status, _, body) = http(addr, "GET", "/app.js", &[], b"").await;
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&body).contains("EventSource"));

    // The event stream: the opening status and position, then the bus.
    let events = sse_until(
        addr,
        &[
            "event: status",
            "event: position",
            "\"source\":\"controller\"",
        ],
    )
    .await;
    assert!(
        events.contains("content-type: text/event-stream"),
        "{events}"
    );

    let m0 = metrics(addr).await;
    let moves0 = get(&m0, "micropos_moves_total");
    let decoded0 = get(&m0, "micropos_vision_frames_decoded_total");

    // Two moves over the socket, one refused by the soft limits.
    cl.call_ok(json!({"cmd": "move", "x_um": 300.0, "y_um": 200.0}))
        .await;
    cl.call_ok(json!({"cmd": "move", "x_um": 600.0, "y_um": 400.0}))
        .await;
    let r = cl
        .call(json!({"cmd": "move", "x_um": 1.0e7, "y_um": 0.0}))
        .await;
    assert_eq!(r["ok"], false, "{r}");
    let code = r["error"]["code"].as_str().unwrap().to_owned();

    // HTTP: anonymous reads work, anonymous moves and stop do not, the
    // token moves, a wrong token does not.
    let (s, v) = command(addr, json!({"cmd": "position", "id": 5}), None).await;
    assert_eq!(
        (s, &v["ok"], &v["id"]),
        (200, &json!(true), &json!(5)),
        "{v}"
    );
    assert!(v["controller"]["x_um"].as_f64().is_some(), "{v}");
    let mv = json!({"cmd": "move", "x_um": 500.0, "y_um": 500.0});
    let (s, v) = command(addr, mv.clone(), None).await;
    assert_eq!(
        (s, &v["error"]["code"]),
        (401, &json!("permission_denied")),
        "{v}"
    );
    let (s, _) = command(addr, json!({"cmd": "stop"}), None).await;
    assert_eq!(s, 401);
    let (s, _) = command(
        addr,
        mv.clone(),
        Some("test-token-5d41402abc4b2a76b9719d911017c59X"),
    )
    .await;
    assert_eq!(s, 401);
    let (s, v) = command(addr, mv.clone(), Some(TOKEN)).await;
    assert_eq!((s, &v["ok"]), (200, &json!(true)), "{v}");
    // The role (operate) bounds the token: reset is admin's.
    let (s, v) = command(addr, json!({"cmd": "reset"}), Some(TOKEN)).await;
    assert_eq!(
        (s, &v["error"]["code"]),
        (403, &json!("permission_denied")),
        "{v}"
    );
    let (s, _) = command(
        addr,
        json!({"cmd": "subscribe", "topics": ["job"]}),
        Some(TOKEN),
    )
    .await;
    assert_eq!(s, 400);
    let (s, _, _) = http(addr, "POST", "/api/command", &[], b"{not json").await;
    assert_eq!(s, 400);

    // A small characterization: frames are decoded, the job advances.
    cl.call_ok(
        json!({"cmd": "characterize", "action": "start", "log": "web.csv", "axes": "x",
           "step_um": 200.0, "x_range_um": 400.0, "y_range_um": 400.0, "cycles": 1,
           "frames_per_point": 2, "settle_s": 0.05, "drift_every_s": 0.0}),
    )
    .await;
    let job = loop {
        let s = cl
            .call_ok(json!({"cmd": "characterize", "action": "status"}))
            .await;
        if s["job"]["state"] != "running" {
            break s["job"].clone();
        }
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    };
    assert_eq!(job["state"], "done", "{job}");

    let m1 = metrics(addr).await;
    // Three client moves succeeded (two socket, one HTTP) and the job's
    // moves on top.
    assert!(get(&m1, "micropos_moves_total") >= moves0 + 3.0, "{m1:?}");
    assert_eq!(
        get(&m1, &format!("micropos_move_errors_total{{code={code}}}")),
        1.0
    );
    assert!(get(&m1, "micropos_vision_frames_decoded_total") > decoded0);
    assert!(
        get(&m1, "micropos_vision_decode_seconds") > 0.0,
        "decode histogram empty"
    );
    assert!(get(&m1, "micropos_vision_decode_quality_bits") > 0.0);
    let total = get(&m1, "micropos_job_points");
    assert!(total > 0.0);
    assert_eq!(get(&m1, "micropos_job_points_done"), total);
    assert_eq!(get(&m1, "micropos_job_progress_ratio"), 1.0);
    assert_eq!(get(&m1, "micropos_job_running"), 0.0);
    assert_eq!(get(&m1, "micropos_fault_latched"), 0.0);
    assert_eq!(get(&m1, "micropos_faults_total"), 0.0);
    let x = get(&m1, "micropos_position_um{axis=x,source=commanded}");
    assert!(x.is_finite());

    // The audit trail names the HTTP client: the move, the refusals. (Its
    // writer thread appends behind a queue: wait for the line.)
    let mut audit = String::new();
    for _ in 0..100 {
        audit = std::fs::read_to_string(data.join("audit.jsonl")).unwrap_or_default();
        if audit.contains("\"via\":\"http\"") && audit.contains("characterize") {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let http_lines: Vec<Value> = audit
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .filter(|v| v["via"] == "http")
        .collect();
    assert!(
        http_lines
            .iter()
            .any(|v| v["cmd"] == "move" && v["outcome"] == "allowed" && v["role"] == "operate"),
        "{audit}"
    );
    assert!(
        http_lines
            .iter()
            .any(|v| v["cmd"] == "move" && v["outcome"] == "denied" && v["role"] == "none"),
        "{audit}"
    );
    assert!(http_lines.iter().all(|v| v["remote"]
        .as_str()
        .is_some_and(|r| r.starts_with("127.0.0.1:"))));

    // A controller line drops and comes back: a latched fault, a
    // reconnect, and the next move refused with its code.
    let connected_x = |s: &Value| s["rig"]["connected"]["x"] == true;
    sim.inject(AxisName::X, Fault::DropLine).unwrap();
    for i in 0.. {
        if !connected_x(&cl.call_ok(json!({"cmd": "status"})).await) {
            break;
        }
        assert!(i < 600, "the line drop was not noticed");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    sim.inject(AxisName::X, Fault::RestoreLine).unwrap();
    for i in 0.. {
        if connected_x(&cl.call_ok(json!({"cmd": "status"})).await) {
            break;
        }
        assert!(i < 600, "no reconnect");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    let r = cl
        .call(json!({"cmd": "move", "x_um": 100.0, "y_um": 100.0}))
        .await;
    assert_eq!(r["error"]["code"], "fault_latched", "{r}");
    let m2 = metrics(addr).await;
    assert!(get(&m2, "micropos_reconnects_total") >= 1.0, "{m2:?}");
    assert!(get(&m2, "micropos_faults_total") >= 1.0, "{m2:?}");
    assert_eq!(get(&m2, "micropos_fault_latched"), 1.0);
    assert_eq!(
        get(&m2, "micropos_move_errors_total{code=fault_latched}"),
        1.0
    );

    daemon.shutdown().await;
    sim.shutdown();
}

/// Whether two JSON values are equal up to the last bits of their numbers
/// (a reply line parsed back is not bit-exact).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-9 * x.abs().max(1.0)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(a, b)| same(a, b))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
        }
        _ => a == b,
    }
}

/// Waits until the job started last is no longer running; its final state.
async fn job_end(cl: &mut Client, cmd: &str) -> Value {
    loop {
        let s = cl.call_ok(json!({"cmd": cmd, "action": "status"})).await;
        if s["job"]["state"] != "running" {
            return s["job"].clone();
        }
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
}

/// `figures` over the socket and `POST /api/command` alike: a clear error
/// before any log, then the figures of a small characterization and
/// validation whose numbers are the logs' own analysis (recomputed here from
/// the files with `plot`); bad names and a corrupted log are error replies.
#[tokio::test(start_paused = true)]
async fn figures_of_the_latest_logs_over_socket_and_http() {
    use micropos::charact::log::read_file;
    use micropos::plot::charact::{backlash_um, mean_errors, repeatability, scans};
    use micropos::plot::validation::gather;

    let WebRig {
        _dir,
        data,
        socket,
        sim,
        daemon,
        addr,
    } = web_rig(17, WebSection::default());
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;

    // Nothing measured yet: the same error reply on both paths.
    for job in ["characterize", "validate"] {
        let req = json!({"cmd": "figures", "job": job});
        let r = cl.call(req.clone()).await;
        assert_eq!(r["error"]["code"], "log_error", "{r}");
        let (s, h) = command(addr, req, None).await;
        assert_eq!(s, 200);
        assert_eq!(h["error"], r["error"]);
    }
    let r = cl
        .call(json!({"cmd": "figures", "job": "characterize"}))
        .await;
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .starts_with("no characterization yet"),
        "{r}"
    );

    cl.call_ok(
        json!({"cmd": "characterize", "action": "start", "log": "fig.csv", "axes": "x",
           "step_um": 200.0, "x_range_um": 400.0, "y_range_um": 400.0, "cycles": 2,
           "frames_per_point": 1, "settle_s": 0.05, "drift_every_s": 0.0}),
    )
    .await;
    assert_eq!(job_end(&mut cl, "characterize").await["state"], "done");

    // The newest characterization, by default, over both paths.
    let sock = cl
        .call_ok(json!({"cmd": "figures", "job": "characterize"}))
        .await;
    let (s, http) = command(addr, json!({"cmd": "figures"}), None).await;
    assert_eq!(s, 200);
    assert_eq!(http["ok"], true, "{http}");
    for k in ["log", "records", "axes", "figures", "notes"] {
        assert_eq!(sock[k], http[k], "{k}");
    }
    assert_eq!(sock["log"], "fig.csv");
    // Against the log's own analysis.
    let log = read_file(data.join("fig.csv")).unwrap();
    assert_eq!(sock["records"], log.records.len());
    let [sx, sy] = scans(&log);
    assert!(sy.is_none(), "x only");
    let sx = sx.unwrap();
    let axes = sock["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 1);
    let a = &axes[0];
    assert_eq!(a["axis"], "x");
    assert_eq!(a["points"], sx.points.len());
    assert_eq!(a["cycles"], 2);
    assert!(same(&a["backlash_um"], &json!(backlash_um(&sx))), "{a}");
    let [fwd, bwd] = mean_errors(&sx);
    assert!(same(&a["mean_error_um"]["forward"], &json!(fwd)));
    assert!(same(&a["mean_error_um"]["backward"], &json!(bwd)));
    let [rf, rb] = repeatability(&sx);
    let rp_max = rf.iter().chain(&rb).map(|p| p.1).fold(f64::NAN, f64::max);
    assert!(same(&a["rp_max_um"], &json!(rp_max)), "{a}");
    // The simulated M-111 has backlash: the stage stops short both ways.
    assert!(a["backlash_um"].as_f64().unwrap() > 0.0, "{a}");
    assert_eq!(sock["figures"].as_array().unwrap().len(), 3, "Figs. 4–6");

    // A small validation: its AP/RP are the log's, and the job's.
    cl.call_ok(
        json!({"cmd": "validate", "action": "start", "test": "square", "modes": ["raw"],
           "cycles": 2, "square_step_um": 4000.0, "origin_x_um": 100.0, "origin_y_um": 100.0,
           "frames_per_point": 1, "settle_s": 0.05, "log": "fig-val.csv"}),
    )
    .await;
    assert_eq!(job_end(&mut cl, "validate").await["state"], "done");
    let job = cl
        .call_ok(json!({"cmd": "validate", "action": "status"}))
        .await;
    let v = cl
        .call_ok(json!({"cmd": "figures", "job": "validate"}))
        .await;
    let (_, vh) = command(addr, json!({"cmd": "figures", "job": "validate"}), None).await;
    assert_eq!(v["results"], vh["results"]);
    assert_eq!(v["log"], "fig-val.csv");
    let vlog = read_file(data.join("fig-val.csv")).unwrap();
    let (sets, _) = gather(&[("fig-val.csv", "fig-val", &vlog)]);
    let raw = sets[0].modes.iter().find(|m| m.name == "raw").unwrap();
    let sum = raw.summary(&sets[0].poses).unwrap();
    let r = &v["results"][0];
    assert_eq!((&r["test"], &r["mode"]), (&json!("square"), &json!("raw")));
    assert!(same(&r["ap_max_um"], &json!(sum.ap_max_um)), "{r}");
    assert!(same(&r["rp_max_um"], &json!(sum.rp_max_um)), "{r}");
    let ap_job = job
        .pointer("/validation/results/square/raw/ap_um")
        .and_then(Value::as_f64)
        .unwrap();
    assert!((ap_job - sum.ap_max_um).abs() < 1e-3, "{ap_job} vs {sum:?}");
    // The characterization is still the newest of its kind.
    let again = cl.call_ok(json!({"cmd": "figures"})).await;
    assert_eq!(again["log"], "fig.csv");

    // Bad input: refused by the parser (HTTP 400) or a log_error reply.
    let r = cl
        .call(json!({"cmd": "figures", "log": "../fig.csv"}))
        .await;
    assert_eq!(r["error"]["code"], "bad_value");
    let (s, _) = command(addr, json!({"cmd": "figures", "job": "diagnose"}), None).await;
    assert_eq!(s, 400);
    std::fs::write(
        data.join("broken.csv"),
        "# job: characterize\nt_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um\n0,scan_x,1,0,0,0,0,\u{1}\n",
    )
    .unwrap();
    for name in ["broken.csv", "missing.csv"] {
        let req = json!({"cmd": "figures", "log": name});
        let r = cl.call(req.clone()).await;
        assert_eq!(r["error"]["code"], "log_error", "{r}");
        assert!(r["error"]["message"].as_str().unwrap().contains(name));
        let (s, h) = command(addr, req, None).await;
        assert_eq!((s, &h["error"]), (200, &r["error"]));
    }
    // The broken log is now the newest characterization: it is named, not
    // skipped for an older one.
    let r = cl.call(json!({"cmd": "figures"})).await;
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("broken.csv"),
        "{r}"
    );

    daemon.shutdown().await;
    sim.shutdown();
}

/// `micropos_vision_residual_um{axis}` = vision, mapped to the stage frame
/// by the active table's tie, minus the controller's position: absent
/// without an active table (and no vision tie: `tie_after_reference` off); after a closed-loop move (vision on target,
/// the controller where the stage's errors put it) it is
/// `target − controller` within the loop's tolerance, and it is exactly
/// what `position` gives through the table's frame.
#[tokio::test(start_paused = true)]
async fn the_vision_residual_is_vision_minus_controller() {
    use micropos::charact::log::read_file;
    use micropos::comp::VisionFrame;
    use micropos::model::XyUm;
    use rand::{Rng, SeedableRng};

    let common::InProcess {
        dir: _dir,
        data,
        socket,
        sim,
        rig: _,
        config: mut c,
    } = common::in_process_rig(29);
    c.web = Some(WebSection {
        listen: "127.0.0.1:0".to_owned(),
        ..WebSection::default()
    });
    // The table's frame is what this measures: no vision tie after the
    // reference run (which would map vision instead of the table's frame).
    c.camera.tie_after_reference = false;
    c.validate().unwrap();
    let tolerance_um = c.closed_loop.tolerance_um;
    let poll = std::time::Duration::from_millis(c.daemon.poll_interval_ms);
    let daemon = common::start_daemon_in_process(c, &sim, &socket);
    let addr = daemon.web_addr.expect("the web listener is bound");
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;

    cl.call_ok(
        json!({"cmd": "characterize", "action": "start", "log": "res.csv",
           "step_um": 500.0, "x_range_um": 1000.0, "y_range_um": 1000.0, "cycles": 1,
           "frames_per_point": 1, "settle_s": 0.05, "drift_every_s": 0.0}),
    )
    .await;
    assert_eq!(job_end(&mut cl, "characterize").await["state"], "done");
    // Frames were decoded, but no table is active: no residual.
    let m = metrics(addr).await;
    assert!(
        !m.keys()
            .any(|k| k.starts_with("micropos_vision_residual_um")),
        "{m:?}"
    );
    let built = cl
        .call_ok(json!({"cmd": "tables", "action": "build", "log": "res.csv",
                        "kinds": ["paper"], "activate": true}))
        .await;
    let frame: VisionFrame = serde_json::from_value(built["frame"].clone()).unwrap();
    let md = read_file(data.join("res.csv")).unwrap().metadata;
    let num = |k: &str| md.get(k).unwrap().parse::<f64>().unwrap();
    let (x0, y0) = (num("x_start_um"), num("y_start_um"));

    let mut rng = rand::rngs::StdRng::seed_from_u64(0x7e5d);
    let mut signs = [[false; 2]; 2];
    for _ in 0..4 {
        let target = [
            x0 + rng.gen_range(100.0..900.0),
            y0 + rng.gen_range(100.0..900.0),
        ];
        cl.call_ok(json!({"cmd": "move", "x_um": target[0], "y_um": target[1],
                          "mode": "closed_loop", "wait": true}))
            .await;
        // The gauge subtracts the controller's last *polled* position:
        // compare a scrape taken once the poll caught up with the move and
        // between two `position` replies showing the same frame.
        let (m, p) = 'settled: {
            for _ in 0..40 {
                tokio::time::sleep(poll).await;
                let before = cl.call_ok(json!({"cmd": "position"})).await;
                let m = metrics(addr).await;
                let p = cl.call_ok(json!({"cmd": "position"})).await;
                let polled = get(&m, "micropos_position_um{axis=x,source=controller}");
                let same_frame = before["vision"]["sequence"] == p["vision"]["sequence"];
                let caught_up = (polled - p["controller"]["x_um"].as_f64().unwrap()).abs() < 1e-3;
                if same_frame && caught_up {
                    break 'settled (m, p);
                }
            }
            panic!("the controller poll never caught up with the move");
        };
        let ctl = [
            p["controller"]["x_um"].as_f64().unwrap(),
            p["controller"]["y_um"].as_f64().unwrap(),
        ];
        let v = frame.to_stage(XyUm {
            x_um: p["vision"]["x_um"].as_f64().unwrap(),
            y_um: p["vision"]["y_um"].as_f64().unwrap(),
        });
        for (k, axis) in ["x", "y"].into_iter().enumerate() {
            let r = get(&m, &format!("micropos_vision_residual_um{{axis={axis}}}"));
            let vision = [v.x_um, v.y_um][k];
            assert!(
                (r - (vision - ctl[k])).abs() < 1e-6,
                "{axis}: gauge {r} vs vision {vision} − controller {}",
                ctl[k]
            );
            // Vision sits on the target: the residual is the controller's
            // distance from it, with this sign.
            let want = target[k] - ctl[k];
            assert!(
                (r - want).abs() <= tolerance_um + 1e-3,
                "{axis}: residual {r} vs target − controller {want}"
            );
            if want.abs() > 10.0 * tolerance_um {
                signs[k][usize::from(want > 0.0)] = true;
            }
        }
    }
    // The stage's errors put the controller off the target (by more than
    // the tolerance) on at least one axis, so the comparison above has
    // weight.
    assert!(signs.iter().flatten().any(|&s| s), "{signs:?}");

    daemon.shutdown().await;
    sim.shutdown();
}

/// The listener holds at most `MAX_CONNECTIONS` connections (and one stop
/// slot per source address; one more is closed unanswered, and served
/// again once one closes) and closes a
/// connection that sends no request header within `IDLE_TIMEOUT`, also
/// after a keep-alive response; before that it stays open.
#[tokio::test(start_paused = true)]
async fn the_listener_caps_connections_and_closes_idle_ones() {
    use micropos::daemon::web::router::{IDLE_TIMEOUT, MAX_CONNECTIONS, MAX_PER_SOURCE};
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    let WebRig {
        _dir,
        sim,
        daemon,
        addr,
        ..
    } = web_rig(5, WebSection::default());

    /// Reads until the peer closes; what it sent (or `None` if it did not
    /// close within `within`).
    async fn until_closed(s: &mut TcpStream, within: Duration) -> Option<Vec<u8>> {
        let mut out = Vec::new();
        match tokio::time::timeout(within, s.read_to_end(&mut out)).await {
            Ok(Ok(_)) => Some(out),
            Ok(Err(_)) => Some(out),
            Err(_) => None,
        }
    }

    // Idle: open and silent stays open short of the timeout, then closes.
    let mut idle = TcpStream::connect(addr).await.unwrap();
    assert!(
        until_closed(&mut idle, IDLE_TIMEOUT / 2).await.is_none(),
        "closed before the idle timeout"
    );
    let got = until_closed(&mut idle, IDLE_TIMEOUT).await;
    assert_eq!(got.map(|b| b.is_empty()), Some(true), "closed, unanswered");

    // Keep-alive: one answered request, then silence: closed likewise.
    let mut ka = TcpStream::connect(addr).await.unwrap();
    ka.write_all(format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut first = [0u8; 12];
    ka.read_exact(&mut first).await.unwrap();
    assert_eq!(&first, b"HTTP/1.1 200");
    let rest = until_closed(&mut ka, IDLE_TIMEOUT * 2).await;
    assert!(rest.is_some(), "a keep-alive connection idles forever");

    // The cap: MAX_CONNECTIONS silent connections held (from four source
    // addresses, each at its own cap), and one stop slot per address
    // besides: one more from a held address is closed without an answer.
    let mut held = Vec::new();
    for i in 0..MAX_CONNECTIONS {
        held.push(connect_from(source(i / MAX_PER_SOURCE), addr).await);
    }
    // Let the listener accept them all before the extra ones.
    tokio::time::sleep(Duration::from_millis(100)).await;
    for i in 0..MAX_CONNECTIONS / MAX_PER_SOURCE {
        held.push(connect_from(source(i), addr).await);
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let mut extra = connect_from(source(0), addr).await;
    let _ = extra
        .write_all(format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .await;
    let got = until_closed(&mut extra, IDLE_TIMEOUT / 2).await;
    assert_eq!(
        got.map(|b| b.len()),
        Some(0),
        "over the cap: closed unanswered"
    );
    // One closes: a new client is served again.
    held.swap_remove(0);
    let mut served = false;
    for _ in 0..50 {
        tokio::time::sleep(Duration::from_millis(20)).await;
        let mut s = connect_from(source(0), addr).await;
        let req = format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
        let _ = s.write_all(req.as_bytes()).await;
        let got = until_closed(&mut s, IDLE_TIMEOUT / 2)
            .await
            .unwrap_or_default();
        if got.starts_with(b"HTTP/1.1 200") {
            served = true;
            break;
        }
    }
    assert!(served, "no client served after a connection closed");
    drop(held);

    daemon.shutdown().await;
    sim.shutdown();
}

/// Loopback source address number `i` (127.0.0.1 + i): one machine's
/// clients from several addresses, as a local flood can make them.
fn source(i: usize) -> std::net::IpAddr {
    let i = u8::try_from(i + 1).unwrap();
    std::net::IpAddr::V4(std::net::Ipv4Addr::new(127, 0, 0, i))
}

/// A TCP connection to `addr` from `from` (port chosen by the system).
async fn connect_from(from: std::net::IpAddr, addr: SocketAddr) -> tokio::net::TcpStream {
    let s = tokio::net::TcpSocket::new_v4().unwrap();
    s.bind(SocketAddr::new(from, 0)).unwrap();
    s.connect(addr).await.unwrap()
}

/// One request on a fresh connection from `from` (`common::http`):
/// status and body.
async fn request_from(
    from: std::net::IpAddr,
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> (u16, String) {
    let s = connect_from(from, addr).await;
    let (status, _, body) = common::http_on(s, addr, method, path, headers, body.as_bytes()).await;
    (status, String::from_utf8_lossy(&body).into_owned())
}

/// A flood cannot starve the web STOP: one address cannot take more than
/// `MAX_PER_SOURCE` connections; with every ordinary connection held (by
/// four addresses), a client gets a stop slot, where `stop` (with the
/// token) halts the moving stage and anything else is 503.
#[tokio::test(start_paused = true)]
async fn a_flood_cannot_starve_the_web_stop() {
    use micropos::daemon::web::router::{MAX_CONNECTIONS, MAX_PER_SOURCE};
    use std::time::Duration;
    let WebRig {
        _dir,
        socket,
        sim,
        daemon,
        addr,
        ..
    } = web_rig(9, operate_with_token());
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;

    // One address holds what it may; more of its connections are not
    // served as ordinary ones (its stop slot answers 503).
    let mut held = Vec::new();
    for _ in 0..MAX_PER_SOURCE {
        held.push(connect_from(source(0), addr).await);
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (status, _) = request_from(source(0), addr, "GET", "/metrics", &[], "").await;
    assert_eq!(status, 503, "a 17th connection of one address was served");
    // Another address is served as usual.
    let (status, _) = request_from(source(9), addr, "GET", "/metrics", &[], "").await;
    assert_eq!(status, 200);

    // Every ordinary connection held.
    for i in MAX_PER_SOURCE..MAX_CONNECTIONS {
        held.push(connect_from(source(i / MAX_PER_SOURCE), addr).await);
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (status, body) = request_from(source(9), addr, "GET", "/metrics", &[], "").await;
    assert_eq!(status, 503, "{body}");
    let json = [("Content-Type", "application/json")];
    let (status, body) = request_from(
        source(9),
        addr,
        "POST",
        "/api/command",
        &json,
        r#"{"cmd":"position"}"#,
    )
    .await;
    assert_eq!(status, 503, "{body}");
    assert!(
        body.contains("busy") && body.contains("only stop"),
        "{body}"
    );

    // The stage moves; the STOP through a stop slot halts it.
    cl.call_ok(json!({"cmd":"move","x_um":14000.0,"y_um":1000.0}))
        .await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let bearer = format!("Bearer {TOKEN}");
    let headers = [json[0], ("Authorization", bearer.as_str())];
    let (status, body) = request_from(
        source(9),
        addr,
        "POST",
        "/api/command",
        &headers,
        r#"{"cmd":"stop"}"#,
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert!(body.contains("\"ok\":true"), "{body}");
    let x_at = |p: &Value| p["controller"]["x_um"].as_f64().unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let a = x_at(&cl.call_ok(json!({"cmd":"position"})).await);
    tokio::time::sleep(Duration::from_millis(500)).await;
    let b = x_at(&cl.call_ok(json!({"cmd":"position"})).await);
    assert!((a - b).abs() < 1.0 && b < 13_000.0, "not halted: {a} → {b}");
    drop(held);

    daemon.shutdown().await;
    sim.shutdown();
}

/// DNS rebinding: a request naming another host (`Host: evil.example`) is
/// refused with 421 on every route, the camera image, positions (through
/// `POST /api/command`), figures and metrics included; the same request
/// with `Host: localhost:PORT` is served.
#[tokio::test(start_paused = true)]
async fn every_route_refuses_a_foreign_host() {
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    let WebRig {
        _dir,
        sim,
        daemon,
        addr,
        ..
    } = web_rig(5, WebSection::default());

    /// The status line's code of one request with `Host: host`.
    async fn status(addr: std::net::SocketAddr, host: &str, method: &str, path: &str) -> String {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let body = if method == "POST" {
            r#"{"cmd":"figures"}"#
        } else {
            ""
        };
        let req = format!(
            "{method} {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        s.write_all(req.as_bytes()).await.unwrap();
        let mut head = [0u8; 12];
        tokio::time::timeout(Duration::from_secs(10), s.read_exact(&mut head))
            .await
            .expect("an answer")
            .unwrap();
        String::from_utf8_lossy(&head[9..12]).into_owned()
    }

    let routes = [
        ("GET", "/"),
        ("GET", "/app.js"),
        ("GET", "/api/camera"),
        ("GET", "/api/camera.png"),
        ("GET", "/metrics"),
        ("POST", "/api/command"),
    ];
    for (method, path) in routes {
        for host in [
            "evil.example",
            "evil.example:8080",
            "localhost.evil.example",
        ] {
            assert_eq!(
                status(addr, host, method, path).await,
                "421",
                "{method} {path} {host}"
            );
        }
    }
    let local = format!("localhost:{}", addr.port());
    for (method, path) in [("GET", "/"), ("GET", "/metrics")] {
        assert_eq!(
            status(addr, &local, method, path).await,
            "200",
            "{method} {path}"
        );
    }
    // The event stream too (its answer never ends: read the status only).
    assert_eq!(
        status(addr, "evil.example", "GET", "/api/events").await,
        "421"
    );

    daemon.shutdown().await;
    sim.shutdown();
}

/// A client that announces a body and stalls is answered 408 and closed
/// within `BODY_TIMEOUT` (before: held open for good), and does not keep
/// the listener from serving the next request.
#[tokio::test(start_paused = true)]
async fn a_stalled_body_is_closed_within_the_timeout() {
    use micropos::daemon::web::command::BODY_TIMEOUT;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    let WebRig {
        _dir,
        sim,
        daemon,
        addr,
        ..
    } = web_rig(5, WebSection::default());

    let mut stalled = Vec::new();
    for _ in 0..8 {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let req = format!(
            "POST /api/command HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"cmd\":"
        );
        s.write_all(req.as_bytes()).await.unwrap();
        stalled.push(s);
    }
    for s in &mut stalled {
        let mut out = Vec::new();
        let r = tokio::time::timeout(BODY_TIMEOUT * 2, s.read_to_end(&mut out)).await;
        assert!(r.is_ok(), "a stalled body held its connection open");
        assert!(
            out.starts_with(b"HTTP/1.1 408"),
            "{}",
            String::from_utf8_lossy(&out)
        );
    }
    let mut s = TcpStream::connect(addr).await.unwrap();
    let req = format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut head = [0u8; 12];
    s.read_exact(&mut head).await.unwrap();
    assert_eq!(&head, b"HTTP/1.1 200");

    daemon.shutdown().await;
    sim.shutdown();
}
