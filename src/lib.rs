//! micropos: makes XY micropositioning stages accurate.
//!
//! The library holds everything that is not process plumbing: the GCS 2.0
//! protocol core (sans-IO), the async C-863 driver, the Megarena pattern
//! (layout, rendering, decoding), camera sources, the stage error model,
//! compensation, metrology (ISO 9283, ISO 230-2), discrepancy diagnosis and
//! the daemon's runtime. The binaries `microposd` and `micropos` and the simulator
//! `hil-sim` are thin shells around it. See `ARCHITECTURE.md`.

#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Unit tests read as one story (set-up, act, check), however long.
#![cfg_attr(test, allow(clippy::too_many_lines))]

pub mod analysis;
pub mod camera;
pub mod charact;
pub mod clock;
pub mod comp;
pub mod daemon;
pub mod driver;
pub mod frame;
pub mod gcs;
pub mod imageio;
pub mod metrology;
pub mod model;
pub mod nofollow;
pub mod pattern;
pub mod plot;

/// An error and its causes on one line, each cause's text once.
///
/// Why not `anyhow`'s `{:#}`: many of the library's errors already put
/// their cause's text in their own message (so that a plain `{e}`, as the
/// daemon's replies use, says everything) and still name it as `source()`;
/// walking the chain then printed it twice ("I/O error: No such file or
/// directory (os error 2): No such file or directory (os error 2)"). A
/// cause whose text the line already holds is skipped.
pub fn error_text(e: &(dyn std::error::Error + 'static)) -> String {
    let mut out = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        cause = c.source();
    }
    out
}

/// Whether the binaries' log lines on stderr may carry ANSI colour codes:
/// only when stderr is a terminal, and not when `NO_COLOR` is set to a
/// non-empty value (<https://no-color.org>).
///
/// Why the binaries ask rather than leave it to `tracing-subscriber`: its
/// default colours whenever its `ansi` feature is on, so a log redirected
/// to a file or piped into `grep` was full of escape sequences.
pub fn stderr_colour() -> bool {
    use std::io::IsTerminal;
    colour_wanted(
        std::io::stderr().is_terminal(),
        std::env::var_os("NO_COLOR").as_deref(),
    )
}

/// [`stderr_colour`]'s rule, apart from the process: colour on a terminal
/// unless `no_color` (the value of `NO_COLOR`) is present and not empty.
pub fn colour_wanted(is_terminal: bool, no_color: Option<&std::ffi::OsStr>) -> bool {
    is_terminal && no_color.is_none_or(|v| v.is_empty())
}

#[cfg(test)]
mod colour_tests {
    use super::colour_wanted;
    use std::ffi::OsStr;

    #[test]
    fn colour_only_on_a_terminal_and_never_under_no_color() {
        assert!(colour_wanted(true, None));
        assert!(colour_wanted(true, Some(OsStr::new(""))));
        assert!(!colour_wanted(true, Some(OsStr::new("1"))));
        assert!(!colour_wanted(false, None));
        assert!(!colour_wanted(false, Some(OsStr::new("1"))));
    }
}

#[cfg(test)]
mod error_text_tests {
    use super::error_text;

    #[derive(Debug, thiserror::Error)]
    enum Inner {
        #[error("I/O error: {0}")]
        Io(#[from] std::io::Error),
    }

    #[derive(Debug, thiserror::Error)]
    #[error("log {path}")]
    struct Outer {
        path: String,
        #[source]
        source: Inner,
    }

    #[test]
    fn each_cause_is_said_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = Outer {
            path: "/x.csv".into(),
            source: Inner::from(io),
        };
        assert_eq!(error_text(&e), "log /x.csv: I/O error: no such file");
        // The inner error alone: its message already holds its cause.
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "gone");
        assert_eq!(error_text(&Inner::from(io)), "I/O error: gone");
    }
}
