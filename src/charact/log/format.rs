//! The format's fixed names, limits and decimals (`docs/log-format.md`): a
//! leaf the reader, the writer and the errors share.

/// The nine mandatory columns, in the order every log must start with.
pub const MANDATORY_COLUMNS: [&str; 9] = [
    "t_s",
    "segment",
    "cycle",
    "x_target_um",
    "y_target_um",
    "x_cmd_um",
    "y_cmd_um",
    "x_meas_um",
    "y_meas_um",
];

/// The optional temperature column; when present it is the tenth column.
pub const TEMP_COLUMN: &str = "temp_c";

/// The optional decoded-angle column: right after the mandatory columns
/// and `temp_c` (when present), before any extra column. Its value is the
/// camera's decoded θ minus the angle the log's vision tie absorbed
/// ([`TIE_THETA_KEY`]), µrad: with `camera.mirrored` set as the optics
/// are, the platform's yaw since the tie, right-handed about +z of the
/// stage frame (+x towards +y).
pub const THETA_COLUMN: &str = "theta_urad";

/// Metadata key of the decoded θ the vision tie absorbed (the pattern's
/// mounting angle as the camera saw it at the tie's anchor, mean of its
/// visits), rad: what [`THETA_COLUMN`] is relative to.
pub const TIE_THETA_KEY: &str = "tie_theta_rad";

/// Metadata key the writer uses to identify the format and its version.
pub const FORMAT_KEY: &str = "format";

/// Value of [`FORMAT_KEY`] written by this version.
pub const FORMAT_ID: &str = "micropos-measurement-log/1";

/// Longest accepted line, terminator included. Guards memory against a
/// binary or corrupt file with no newline; real lines are ~150 bytes.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Largest magnitude accepted for any number (µm, s, °C). Bounds the values
/// to physically meaningful ones and keeps the written decimals exact
/// (f64 resolves 1e-6 at this magnitude).
pub const MAX_ABS_VALUE: f64 = 1.0e9;

/// Decimals written for positions in µm: 0.1 nm, below the camera's
/// nanometre-class resolution.
pub const POSITION_DECIMALS: usize = 4;
/// Decimals written for `t_s`: 1 µs, finer than any frame rate.
pub const TIME_DECIMALS: usize = 6;
/// Decimals written for `temp_c`: 1 mK.
pub const TEMP_DECIMALS: usize = 3;
/// Decimals written for `theta_urad`: 0.01 µrad, far below a frame's θ
/// error (tens of µrad).
pub const THETA_DECIMALS: usize = 2;

/// At most this many warnings are kept; the rest are only counted.
pub const MAX_WARNINGS: usize = 1000;
