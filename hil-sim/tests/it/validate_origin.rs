//! `validate start` out of the box, on microposd with the in-process
//! simulated rig (paused clock) configured as `config/microposd-sim.toml`:
//! a 1000 × 500 µm characterization centred in the travel. From its start
//! the paper's poses (8 × 4 mm) leave the travel; the default origin moves
//! to the travel's start instead, and an origin that does not fit is
//! refused naming the CLI flags and the range of origins that fits.

use crate::common::{self, Client};
use micropos::daemon::jobs::validate::ORIGIN_CLEARANCE_UM;
use serde_json::{json, Value};

/// Paper coordinates spanned by the square and Table II together, µm.
const SPAN_X_UM: [f64; 2] = [10.0, 8196.0];
const SPAN_Y_UM: [f64; 2] = [10.0, 4010.0];

fn limits(status: &Value, axis: &str) -> (f64, f64) {
    let l = &status["rig"]["limits"][axis];
    let l = if l.is_null() {
        &status["limits"][axis]
    } else {
        l
    };
    (l[0].as_f64().unwrap(), l[1].as_f64().unwrap())
}

#[tokio::test(start_paused = true)]
async fn validate_start_fits_the_travel_by_default_and_names_its_flags() {
    let common::InProcess {
        dir: _dir,
        data,
        socket,
        sim,
        rig: _,
        config: mut c,
    } = common::in_process_rig(29);
    // config/microposd-sim.toml's scan: 1000 × 500 µm, centred.
    c.characterize.x_start_um = None;
    c.characterize.y_start_um = None;
    c.characterize.x_range_um = 1000.0;
    c.characterize.y_range_um = 500.0;
    c.validate().unwrap();
    let _daemon = common::start_daemon_in_process(c, &sim, &socket);
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;
    let st = cl.call_ok(json!({"cmd": "status"})).await;
    let (xl, yl) = (limits(&st, "x_um"), limits(&st, "y_um"));
    // The characterization start: from there the poses leave the travel
    // in x (the old default, refused).
    let start = [(xl.0 + xl.1 - 1000.0) / 2.0, (yl.0 + yl.1 - 500.0) / 2.0];
    assert!(start[0] + SPAN_X_UM[1] > xl.1, "{xl:?}: the case needs it");
    let req = |origin: Option<[f64; 2]>| {
        let mut v = json!({"cmd": "validate", "action": "start", "test": "both",
                           "modes": ["raw"], "cycles": 1, "log": "v.csv"});
        if let Some([x, y]) = origin {
            v["origin_x_um"] = json!(x);
            v["origin_y_um"] = json!(y);
        }
        v
    };
    // Named, it is refused with the flags and the range that fits.
    let r = cl.call(req(Some(start))).await;
    assert_eq!(r["error"]["code"], "out_of_travel", "{r}");
    let msg = r["error"]["message"].as_str().unwrap();
    let range = format!(
        "an origin x {:.1} … {:.1} µm, y {:.1} … {:.1} µm keeps every one inside the travel",
        xl.0 - SPAN_X_UM[0],
        xl.1 - SPAN_X_UM[1],
        yl.0 - SPAN_Y_UM[0],
        yl.1 - SPAN_Y_UM[1]
    );
    for part in [
        "validation pose 6 would be at",
        range.as_str(),
        "validate start --origin-x-um X --origin-y-um Y",
    ] {
        assert!(msg.contains(part), "{part:?} not in {msg}");
    }
    assert!(!data.join("v.csv").exists(), "refused before the log");
    // Not named: x from the travel's start, y (which fits) the scan's start.
    let r = cl.call_ok(req(None)).await;
    let o = [
        r["origin"]["x_um"].as_f64().unwrap(),
        r["origin"]["y_um"].as_f64().unwrap(),
    ];
    assert_eq!(
        o,
        [xl.0 + ORIGIN_CLEARANCE_UM - SPAN_X_UM[0], start[1]],
        "{r}"
    );
    assert!(o[0] + SPAN_X_UM[1] <= xl.1 && o[1] + SPAN_Y_UM[1] <= yl.1);
    assert_eq!(r["job"]["state"], "running", "{r}");
    cl.call_ok(json!({"cmd": "validate", "action": "cancel"}))
        .await;
}
