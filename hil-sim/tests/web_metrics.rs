//! The web listener on microposd with the in-process simulated rig (paused
//! clock): `GET /metrics` parses as Prometheus text and its values move
//! with activity (moves, a refused move's error code, frames decoded,
//! decode times, job progress); `POST /api/command` runs the socket's
//! commands with the socket's rules (anonymous reads only, the token for
//! anything else, the role, the audit trail); `GET /api/events` streams
//! the event bus; the page and its script are served.

mod common;
use common::{http, Client};
use hil_sim::run::{daemon_config, RunPlan};
use hil_sim::{AxisName, Fault};
use micropos::daemon::config::WebSection;
use prometheus_parse::{Scrape, Value as PValue};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::net::SocketAddr;

const TOKEN: &str = "test-token-0123456789abcdef";

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
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    let cfg = common::serve_config(&rig_dir, 50.0, 3);
    let rig_cfg = cfg.rig.clone();
    let sim = common::serve_in_process(cfg);
    let socket = dir.path().join("d.sock");
    let mut c = daemon_config(&rig_dir, &data, &socket, &rig_cfg, &RunPlan::reduced()).unwrap();
    c.web = Some(WebSection {
        listen: "127.0.0.1:0".to_owned(),
        control: true,
        role: "operate".to_owned(),
        token: Some(TOKEN.to_owned()),
        ..WebSection::default()
    });
    c.validate().unwrap();
    let daemon = common::start_daemon_in_process(c, &sim, &socket);
    let addr = daemon.web_addr.expect("the web listener is bound");
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
    let (s, _) = command(addr, mv.clone(), Some("test-token-0123456789abcdeX")).await;
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
