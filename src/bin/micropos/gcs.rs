//! `micropos gcs`: a raw GCS console for bringing up real hardware.
//!
//! Every line typed (or given on the command line) is sent as is, its answer
//! printed, and `ERR?` asked after it, as PI's own tools do, so a refused
//! command never goes unnoticed. `#4`, `#5`, `#7` and `#24` are sent as the
//! single-character commands. The controller is identified first, so a
//! missing device, a wrong baud rate or a non-PI device is reported before
//! anything else is sent.

use anyhow::Context;
use micropos::driver::{
    AxisEvent, ConsoleReply, Controller, Framing, Line, LineOptions, SerialConnector,
    SerialSettings,
};
use micropos::gcs::frame::Address;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use tokio::sync::broadcast;

/// Arguments of `micropos gcs`.
#[derive(Debug, clap::Args)]
pub struct GcsArgs {
    /// Serial device of the controller (e.g. /dev/ttyUSB0).
    #[arg(long)]
    port: PathBuf,
    /// Daisy-chain address 1..=16 (sends the address prefix); omit for a
    /// controller alone on its line.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=16))]
    address: Option<u8>,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Character framing.
    #[arg(long, default_value = "8N1")]
    framing: Framing,
    /// Answer timeout in milliseconds.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    timeout_ms: u64,
    /// Command to send (e.g. `POS? 1`, `#7`); without it, commands are read
    /// from standard input, one per line.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    command: Vec<String>,
}

/// Runs the console; the exit code is 1 when a one-shot command was refused.
pub async fn run(a: GcsArgs) -> anyhow::Result<ExitCode> {
    let settings = SerialSettings {
        baud: a.baud,
        framing: a.framing,
    };
    let context = || format!("{} at {} baud {}", a.port.display(), a.baud, a.framing);
    let (events, _) = broadcast::channel(64);
    let line = Line::open(
        SerialConnector::new(&a.port, settings),
        LineOptions::default(),
        events.clone(),
    )
    .await
    .with_context(context)?;
    let mut rx = events.subscribe();
    let addr = a
        .address
        .map(Address::new)
        .transpose()
        .context("bad address")?;
    let ctl = Controller::new(line, addr, Duration::from_millis(a.timeout_ms), events);
    let (idn, _) = ctl.identify().await.with_context(context)?;
    let unknown = |v: &str| {
        if v.is_empty() {
            "not given".to_owned()
        } else {
            v.to_owned()
        }
    };
    eprintln!(
        "connected to {} {} (serial {}, firmware {}) on {}{}",
        idn.vendor,
        idn.model,
        unknown(&idn.serial),
        unknown(&idn.firmware),
        ctl.label(),
        if idn.is_c863() {
            ""
        } else {
            "; not a C-863: this console talks to it, `micropos axes` and the daemon will not drive it"
        }
    );
    if !a.command.is_empty() {
        let text = a.command.join(" ");
        let reply = ctl.console(&text).await.with_context(context)?;
        print_reply(&reply);
        report_events(&mut rx);
        return Ok(if reply.error.is_ok() {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        });
    }
    let interactive = std::io::stdin().is_terminal();
    // Standard input is read on a blocking thread, line by line.
    let (tx, mut lines) = tokio::sync::mpsc::channel::<std::io::Result<String>>(1);
    std::thread::spawn(move || {
        for l in std::io::stdin().lines() {
            if tx.blocking_send(l).is_err() {
                return;
            }
        }
    });
    loop {
        if interactive {
            eprint!("gcs> ");
            let _ = std::io::stderr().flush();
        }
        let Some(text) = lines.recv().await else {
            break;
        };
        let text = text.context("reading standard input")?;
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        if text == "quit" || text == "exit" {
            break;
        }
        match ctl.console(text).await {
            Ok(reply) => print_reply(&reply),
            Err(e) => println!("error: {e}"),
        }
        report_events(&mut rx);
    }
    Ok(ExitCode::SUCCESS)
}

fn print_reply(r: &ConsoleReply) {
    match &r.answer {
        Some(a) => {
            for l in a.raw_lines() {
                println!("{}", printable(l));
            }
        }
        None if r.silent => println!("(no answer)"),
        None => {}
    }
    println!("ERR? {}", r.error);
}

/// Shows the line as text, with bytes that are not printable ASCII as `0xNN`
/// (so the `#7` answer reads `0xB1`).
fn printable(l: &[u8]) -> String {
    let mut s = String::new();
    for &b in l {
        if (0x20..0x7F).contains(&b) {
            s.push(char::from(b));
        } else {
            s.push_str(&format!("0x{b:02X}"));
        }
    }
    match l {
        [0xB1] => s.push_str(" (ready)"),
        [0xB0] => s.push_str(" (busy)"),
        _ => {}
    }
    s
}

fn report_events(rx: &mut broadcast::Receiver<AxisEvent>) {
    while let Ok(e) = rx.try_recv() {
        match e {
            AxisEvent::Noise { text, .. } => {
                eprintln!("note: unexpected bytes on the line: {text:?}")
            }
            AxisEvent::Disconnected { line, reason } => eprintln!("note: {line} down: {reason}"),
            AxisEvent::Connected { line } => eprintln!("note: {line} (re)connected"),
            other => eprintln!("note: {other:?}"),
        }
    }
}
