//! The daemon's decode checks the period against `[camera] pixel_um`: on
//! the in-process simulated rig (4 µm pattern, 0.4 µm pixels) a daemon
//! configured with `period_um = 8` measured every position twice too far
//! and said nothing; with the pixel size configured, a job's first
//! measurement fails naming the period that fits.

use crate::common::{self, Client};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

#[tokio::test(start_paused = true)]
async fn a_wrong_period_fails_the_measurement_naming_the_period_that_fits() {
    let common::InProcess {
        dir: _dir,
        data: _,
        socket,
        sim,
        rig: rig_cfg,
        config: mut c,
    } = common::in_process_rig(31);
    assert_eq!(c.camera.pixel_um, Some(rig_cfg.camera.pixel_um));
    assert_eq!(c.camera.period_um, 4.0);
    c.camera.period_um = 8.0;
    c.daemon.job_retries = 0;
    c.validate().unwrap();
    let _daemon = common::start_daemon_in_process(c, &sim, &socket);
    let mut events = Client::connect(&socket).await;
    events
        .call_ok(json!({"cmd": "subscribe", "topics": ["job"]}))
        .await;
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;
    cl.call_ok(
        json!({"cmd": "characterize", "action": "start", "log": "c.csv",
                      "axes": "x", "step_um": 200.0, "x_range_um": 400.0,
                      "y_range_um": 400.0, "cycles": 1, "frames_per_point": 1,
                      "settle_s": 0.05, "drift_every_s": 0.0}),
    )
    .await;
    let t = Instant::now();
    let end: Value = loop {
        assert!(t.elapsed() < Duration::from_secs(60), "job did not end");
        let v = events.line().await;
        if v["event"] == "job" && v["state"] != "running" {
            break v;
        }
    };
    assert_eq!(end["state"], "failed", "{end}");
    let err = end["error"].as_str().unwrap_or_default();
    assert!(
        err.contains("with a period of 8 µm")
            && err.contains("the pattern's period is about 4.000 µm"),
        "{err}"
    );
    let st = cl.call_ok(json!({"cmd": "status"})).await;
    let last = st["camera"]["last_error"].as_str().unwrap_or_default();
    assert!(
        last.contains("the pattern's period is about 4.000 µm"),
        "{st}"
    );
}
