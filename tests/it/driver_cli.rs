//! `micropos gcs` / `micropos axes` as a person meets them: exit codes and
//! the messages for a missing device, a device that does not answer (wrong
//! baud rate) and a device that is not a PI controller. The "devices" are
//! ptys with a small responder on the master side.

use std::path::PathBuf;
use std::process::Output;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPort;

async fn micropos(args: &[&str]) -> Output {
    tokio::process::Command::new(env!("CARGO_BIN_EXE_micropos"))
        .args(args)
        .output()
        .await
        .unwrap()
}

/// A pty whose master answers every line with `reply` (None: never answers).
fn device(reply: Option<&'static [u8]>) -> PathBuf {
    device_with(reply, None)
}

/// Like [`device`], but `ERR?` gets `err` when given (a controller with no
/// error to report answers `0`).
fn device_with(reply: Option<&'static [u8]>, err: Option<&'static [u8]>) -> PathBuf {
    let (mut master, slave) = tokio_serial::SerialStream::pair().unwrap();
    let path = PathBuf::from(slave.name().unwrap());
    drop(slave);
    tokio::spawn(async move {
        let mut buf = [0u8; 256];
        loop {
            match master.read(&mut buf).await {
                Ok(0) => return,
                Ok(n) => {
                    let line = &buf[..n];
                    let asks_err = line.windows(4).any(|w| w == b"ERR?");
                    let answer = match err {
                        Some(e) if asks_err => Some(e),
                        _ => reply,
                    };
                    if let Some(r) = answer {
                        if line.contains(&b'\n') {
                            let _ = master.write_all(r).await;
                        }
                    }
                }
                // EIO while no slave is open.
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(5)).await,
            }
        }
    });
    path
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn usage_errors_exit_2() {
    let o = micropos(&["axes", "status"]).await;
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = micropos(&["gcs"]).await;
    assert_eq!(o.status.code(), Some(2));
    let o = micropos(&["gcs", "--port", "/dev/null", "--address", "17", "POS?"]).await;
    assert_eq!(o.status.code(), Some(2));
    let o = micropos(&["axes", "--port-x", "/a", "status"]).await;
    assert_eq!(o.status.code(), Some(2));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn missing_device_is_named() {
    let o = micropos(&["gcs", "--port", "/nonexistent/ttyX", "POS? 1"]).await;
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("no serial device at /nonexistent/ttyX"), "{e}");
    let o = micropos(&[
        "axes",
        "--port-x",
        "/nonexistent/a",
        "--port-y",
        "/b",
        "status",
    ])
    .await;
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("/nonexistent/a"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_device_suggests_the_baud_rate() {
    let dev = device(None);
    let o = micropos(&[
        "gcs",
        "--port",
        dev.to_str().unwrap(),
        "--baud",
        "9600",
        "--timeout-ms",
        "100",
        "*IDN?",
    ])
    .await;
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("at 9600 baud") && e.contains("wrong baud rate"),
        "{e}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn non_pi_device_is_refused() {
    let dev = device(Some(b"Arduino Uno ready\n"));
    let o = micropos(&[
        "gcs",
        "--port",
        dev.to_str().unwrap(),
        "--timeout-ms",
        "200",
    ])
    .await;
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("not a PI controller") && e.contains("Arduino"),
        "{e}"
    );
}

/// An older PI controller answers `*IDN?` in two fields (E-861 firmware):
/// the console identifies it and talks to it; `axes` refuses to drive it,
/// saying it is not a C-863.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn any_pi_model_is_identified_and_only_axes_refuses_it() {
    const E861: &[u8] = b"(c)2013 Physik Instrumente(PI) Karlsruhe, E-861 Version 7.2.0\n";
    let dev = device_with(Some(E861), Some(b"0\n"));
    let o = micropos(&[
        "gcs",
        "--port",
        dev.to_str().unwrap(),
        "--timeout-ms",
        "300",
        "*IDN?",
    ])
    .await;
    let e = stderr(&o);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{e}\n{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert!(e.contains("E-861") && e.contains("not a C-863"), "{e}");
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("E-861 Version 7.2.0"),
        "{o:?}"
    );

    let (x, y) = (
        device_with(Some(E861), Some(b"0\n")),
        device_with(Some(E861), Some(b"0\n")),
    );
    let o = micropos(&[
        "axes",
        "--port-x",
        x.to_str().unwrap(),
        "--port-y",
        y.to_str().unwrap(),
        "--timeout-ms",
        "300",
        "status",
    ])
    .await;
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("E-861") && e.contains("not a C-863"), "{e}");
}
