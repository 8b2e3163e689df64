//! `move` with `tool` on microposd with the in-process simulated rig
//! (paused clock): the watched point is sent to `tool − R_z(θ)·offset` with
//! θ the active table's `[yaw]` at the plan's own command, θ = 0 (and the
//! reply says so) for a table without yaw tables; an unknown tool is
//! refused naming the configured ones.

use crate::common::{Client, DaemonRig};
use micropos::comp::yaw::{YawAxisTables, YawDirTable};
use micropos::comp::{
    AxisTables, CompFile, CompTable, DirTable, Interpolation, SourceInfo, YawTables,
};
use micropos::daemon::config::ToolPoint;
use serde_json::{json, Value};

/// Per-axis yaw slopes of the table, µrad per µm of travel from 1000 µm.
const SLOPE_X: f64 = 0.05;
const SLOPE_Y: f64 = -0.02;

/// A zero-error lookup table over x, y 1000 … 2000 µm, with yaw tables
/// linear in each axis (`yaw`) or without.
fn table(yaw: bool) -> CompFile {
    let pos = vec![1000.0, 1500.0, 2000.0];
    let dir = || DirTable {
        ex_um: vec![0.0; 3],
        ey_um: vec![0.0; 3],
        visits: vec![1; 3],
        positions_um: pos.clone(),
    };
    let axis = || AxisTables {
        hold_um: 1000.0,
        forward: dir(),
        backward: dir(),
    };
    let t = CompTable {
        interpolation: Interpolation::Linear,
        x_scan: axis(),
        y_scan: axis(),
        delta_x_slope: 0.0,
    };
    let yaw_dir = |slope: f64| YawDirTable {
        yaw_urad: pos.iter().map(|p| slope * (p - 1000.0)).collect(),
        visits: vec![1; 3],
        positions_um: pos.clone(),
    };
    let yaw_axis = |slope: f64| YawAxisTables {
        forward: yaw_dir(slope),
        backward: yaw_dir(slope),
    };
    let mut f = CompFile::lookup(t, "2026-12-02T12:00:00Z", SourceInfo::default());
    f.yaw = yaw.then(|| YawTables {
        interpolation: Interpolation::Linear,
        x_scan: yaw_axis(SLOPE_X),
        y_scan: yaw_axis(SLOPE_Y),
        y_hold_um: 1000.0,
    });
    f
}

fn commanded(m: &Value) -> [f64; 2] {
    [
        m["commanded"]["x_um"].as_f64().unwrap(),
        m["commanded"]["y_um"].as_f64().unwrap(),
    ]
}

#[tokio::test(start_paused = true)]
async fn a_tool_move_aims_the_pattern_through_the_yaw() {
    let offset = [3000.0, 20000.0];
    let rig = DaemonRig::in_process(31, 50.0, |c| {
        c.tools
            .points
            .insert("tip".into(), ToolPoint { offset_um: offset });
        c.tools.active = Some("tip".into());
    })
    .await;
    let mut cl = Client::connect(&rig.socket).await;
    let s = cl.call_ok(json!({"cmd": "status"})).await;
    assert_eq!(
        s["tools"],
        json!({"active": "tip", "offsets_um": {"tip": offset}}),
        "{s}"
    );
    for (name, yaw) in [("yaw.toml", true), ("flat.toml", false)] {
        table(yaw).write_path(rig.data.join(name)).unwrap();
        cl.call_ok(json!({"cmd": "tables", "action": "load", "name": name}))
            .await;
    }
    let tool = [4500.0, 21300.0];
    let mv = json!({"cmd": "move", "x_um": tool[0], "y_um": tool[1], "mode": "compensated",
                    "wait": true, "tool": "tip"});

    cl.call_ok(json!({"cmd": "tables", "action": "activate", "name": "yaw.toml"}))
        .await;
    let m = cl.call_ok(mv.clone()).await;
    let c = commanded(&m);
    let theta_urad = SLOPE_X * (c[0] - 1000.0) + SLOPE_Y * (c[1] - 1000.0);
    let t = &m["tool"];
    assert_eq!(t["yaw_source"], "table", "{m}");
    assert_eq!(t["name"], "tip", "{m}");
    // The yaw of the command the plan ended with, and the command is the
    // tool's target less the arm turned by it (a zero-error table).
    assert!(
        (t["yaw_urad"].as_f64().unwrap() - theta_urad).abs() < 1e-6,
        "{m}"
    );
    let (s, co) = (theta_urad * 1e-6).sin_cos();
    let want = [
        tool[0] - (co * offset[0] - s * offset[1]),
        tool[1] - (s * offset[0] + co * offset[1]),
    ];
    for i in 0..2 {
        assert!((c[i] - want[i]).abs() < 1e-6, "{c:?} vs {want:?}: {m}");
    }
    // ≈ 19 µrad on a 20 mm arm: ≈ 0.38 µm in x from the unturned arm.
    assert!(
        theta_urad > 15.0 && (c[0] - (tool[0] - offset[0])).abs() > 0.3,
        "{m}"
    );

    // A table without yaw: θ = 0, and the reply says so.
    cl.call_ok(json!({"cmd": "tables", "action": "activate", "name": "flat.toml"}))
        .await;
    let m = cl.call_ok(mv.clone()).await;
    assert_eq!(m["tool"]["yaw_source"], "none", "{m}");
    assert_eq!(m["tool"]["yaw_urad"], 0.0, "{m}");
    let c = commanded(&m);
    assert!(
        (c[0] - 1500.0).abs() < 1e-9 && (c[1] - 1300.0).abs() < 1e-9,
        "{m}"
    );

    // An unknown tool: refused, naming the configured ones.
    let mut bad = mv.clone();
    bad["tool"] = json!("pipette");
    let r = cl.call(bad).await;
    assert_eq!(r["error"]["code"], "bad_value", "{r}");
    assert!(
        r["error"]["message"].as_str().unwrap().contains("tip"),
        "{r}"
    );
}
