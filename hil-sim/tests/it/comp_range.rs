//! Compensation that knows its range, on microposd with the in-process
//! simulated rig (paused clock): a compensated move outside the active
//! table's characterized area is refused (`outside_table`, the message
//! naming the area and the target) under the default `[compensation]
//! outside_table = "refuse"`, moves with a warning under `"warn"`; a
//! validation whose poses leave the table's area is refused before it
//! moves, saying which origins would keep them inside (here: none).

use crate::common::{Client, DaemonRig};
use micropos::comp::{AxisTables, CompFile, CompTable, DirTable, Interpolation, SourceInfo};
use micropos::daemon::config::OutsideTable;
use serde_json::{json, Value};

/// A 1000 × 500 µm lookup table (x 1000 … 2000, y 1000 … 1500 µm) with a
/// −22.65 µm x error, the case.
fn small_table() -> CompFile {
    let dir = |positions: Vec<f64>, ex: f64| DirTable {
        ex_um: vec![ex; positions.len()],
        ey_um: vec![0.0; positions.len()],
        visits: vec![1; positions.len()],
        positions_um: positions,
    };
    let x = vec![1000.0, 1500.0, 2000.0];
    let y = vec![1000.0, 1250.0, 1500.0];
    let table = CompTable {
        interpolation: Interpolation::Linear,
        x_scan: AxisTables {
            hold_um: 1000.0,
            forward: dir(x.clone(), 22.65),
            backward: dir(x, 22.65),
        },
        y_scan: AxisTables {
            hold_um: 1000.0,
            forward: dir(y.clone(), 0.0),
            backward: dir(y, 0.0),
        },
        delta_x_slope: 0.0,
    };
    CompFile::lookup(table, "2026-11-28T20:00:00Z", SourceInfo::default())
}

struct Setup {
    rig: DaemonRig,
    cl: Client,
}

/// The in-process rig and daemon with `outside_table`, the small table
/// written to the data directory, loaded and activated, axes referenced.
async fn setup(outside: OutsideTable) -> Setup {
    let rig = DaemonRig::in_process(23, 50.0, |c| c.compensation.outside_table = outside).await;
    let mut cl = Client::connect(&rig.socket).await;
    small_table()
        .write_path(rig.data.join("small.toml"))
        .unwrap();
    cl.call_ok(json!({"cmd": "tables", "action": "load", "name": "small.toml"}))
        .await;
    cl.call_ok(json!({"cmd": "tables", "action": "activate", "name": "small.toml"}))
        .await;
    Setup { rig, cl }
}

fn commanded(p: &Value) -> [f64; 2] {
    [
        p["commanded"]["x_um"].as_f64().unwrap(),
        p["commanded"]["y_um"].as_f64().unwrap(),
    ]
}

#[tokio::test(start_paused = true)]
async fn compensated_move_outside_the_table_is_refused_by_default() {
    let mut s = setup(OutsideTable::Refuse).await;
    // Inside: compensated by the table.
    let m =
        s.cl.call_ok(json!({"cmd": "move", "x_um": 1500.0, "y_um": 1200.0,
                        "mode": "compensated", "wait": true}))
            .await;
    assert!(m.get("outside_table").is_none(), "{m}");
    assert_eq!(m["target"]["x_um"], 1500.0, "{m}");
    let before = commanded(&s.cl.call_ok(json!({"cmd": "position"})).await);
    // Outside: refused, nothing moves.
    let r =
        s.cl.call(json!({"cmd": "move", "x_um": 2500.0, "y_um": 2300.0,
                     "mode": "compensated", "wait": true}))
            .await;
    assert_eq!(r["error"]["code"], "outside_table", "{r}");
    let msg = r["error"]["message"].as_str().unwrap();
    for part in [
        "(2500.0, 2300.0) µm",
        "x 1000.0 … 2000.0 µm, y 1000.0 … 1500.0 µm",
        "small.toml",
        "490.0 µm in x and 790.0 µm in y",
    ] {
        assert!(msg.contains(part), "{part:?} not in {msg}");
    }
    let after = commanded(&s.cl.call_ok(json!({"cmd": "position"})).await);
    assert_eq!(before, after, "a refused move does not move");
    // Within the margin (10 µm) beyond the last point: allowed.
    s.cl.call_ok(json!({"cmd": "move", "x_um": 2005.0, "y_um": 1505.0,
                        "mode": "compensated", "wait": true}))
        .await;
    // Raw moves are not compensated, so not checked.
    s.cl.call_ok(json!({"cmd": "move", "x_um": 2500.0, "y_um": 2300.0, "wait": true}))
        .await;
}

#[tokio::test(start_paused = true)]
async fn warn_mode_moves_and_says_so() {
    let mut s = setup(OutsideTable::Warn).await;
    let m =
        s.cl.call_ok(json!({"cmd": "move", "x_um": 2500.0, "y_um": 2300.0,
                        "mode": "compensated", "wait": true}))
            .await;
    let o = &m["outside_table"];
    assert_eq!(o["policy"], "warn", "{m}");
    assert_eq!(o["area"]["x_um"], json!([1000.0, 2000.0]), "{m}");
    assert_eq!(o["outside_by_um"], json!([490.0, 790.0]), "{m}");
    assert!(
        o["warning"]
            .as_str()
            .unwrap()
            .contains("holds its end values"),
        "{m}"
    );
    assert_eq!(m["target"], json!({"x_um": 2500.0, "y_um": 2300.0}), "{m}");
    let cmd = commanded(&s.cl.call_ok(json!({"cmd": "position"})).await);
    assert!((cmd[0] - (2500.0 + 22.65)).abs() < 1e-6, "{cmd:?}");
}

#[tokio::test(start_paused = true)]
async fn validation_leaving_the_table_is_refused_before_it_moves() {
    let mut s = setup(OutsideTable::Refuse).await;
    s.cl.call_ok(json!({"cmd": "move", "x_um": 1200.0, "y_um": 1100.0, "wait": true}))
        .await;
    let before = commanded(&s.cl.call_ok(json!({"cmd": "position"})).await);
    let r =
        s.cl.call(
            json!({"cmd": "validate", "action": "start", "test": "random",
                     "modes": ["raw", "table"], "table": "small.toml", "cycles": 1,
                     "origin_x_um": 1000.0, "origin_y_um": 1000.0, "log": "v.csv"}),
        )
        .await;
    assert_eq!(r["error"]["code"], "outside_table", "{r}");
    let msg = r["error"]["message"].as_str().unwrap();
    assert!(msg.contains("mode table pose 1"), "{msg}");
    assert!(msg.contains("origin is (1000.0, 1000.0) µm"), "{msg}");
    // Table II spans more than the table holds: no origin helps, and the
    // refusal says so instead of suggesting another origin.
    assert!(
        msg.contains(
            "no origin keeps every one inside that area and the travel, too short in x \
             (7161.0 µm of poses, 1020.0 µm available) and y (3956.0 µm of poses, 520.0 µm \
             available); characterize an area that covers them"
        ),
        "{msg}"
    );
    assert!(
        !s.rig.data.join("v.csv").exists(),
        "no log: the job never started"
    );
    let st = s.cl.call_ok(json!({"cmd": "validate"})).await;
    assert!(st["job"].is_null(), "{st}");
    let after = commanded(&s.cl.call_ok(json!({"cmd": "position"})).await);
    assert_eq!(before, after, "nothing moved");
}
