//! How a line gets its byte stream: a [`Connector`] opens (and, after a
//! fault, reopens) it. The line task is generic over the connector, so the
//! same code runs over a real serial device ([`SerialConnector`]) and over an
//! in-memory `tokio::io::duplex` stream in tests.

use super::error::DriverError;
use serde::{Deserialize, Serialize};
use std::future::Future;
use std::path::{Path, PathBuf};
use tokio::io::{AsyncRead, AsyncWrite};

/// Opens the byte stream of one line; called again after every fault.
pub trait Connector: Send + 'static {
    /// The stream type.
    type Io: AsyncRead + AsyncWrite + Unpin + Send + 'static;

    /// Opens the stream. Must not block the runtime.
    fn connect(&mut self) -> impl Future<Output = Result<Self::Io, DriverError>> + Send;

    /// The name used in errors and events (the device path).
    fn name(&self) -> String;
}

/// Character framing of the serial line, written like `"8N1"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct Framing {
    /// Data bits, 5..=8.
    pub data_bits: u8,
    /// Parity: `'N'`, `'E'` or `'O'`.
    pub parity: char,
    /// Stop bits, 1 or 2.
    pub stop_bits: u8,
}

impl Default for Framing {
    /// 8N1, the C-863 factory setting.
    fn default() -> Self {
        Self {
            data_bits: 8,
            parity: 'N',
            stop_bits: 1,
        }
    }
}

impl std::str::FromStr for Framing {
    type Err = DriverError;

    fn from_str(s: &str) -> Result<Self, DriverError> {
        let bad = || {
            DriverError::Invalid(format!(
                "serial framing {s:?} is not of the form 8N1 (data bits 5-8, parity N/E/O, stop bits 1-2)"
            ))
        };
        let b = s.as_bytes();
        if b.len() != 3 {
            return Err(bad());
        }
        let data_bits = b[0].wrapping_sub(b'0');
        let parity = char::from(b[1]).to_ascii_uppercase();
        let stop_bits = b[2].wrapping_sub(b'0');
        if !(5..=8).contains(&data_bits) || !"NEO".contains(parity) || !(1..=2).contains(&stop_bits)
        {
            return Err(bad());
        }
        Ok(Self {
            data_bits,
            parity,
            stop_bits,
        })
    }
}

impl TryFrom<String> for Framing {
    type Error = DriverError;
    fn try_from(s: String) -> Result<Self, DriverError> {
        s.parse()
    }
}

impl From<Framing> for String {
    fn from(f: Framing) -> String {
        f.to_string()
    }
}

impl std::fmt::Display for Framing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}{}{}", self.data_bits, self.parity, self.stop_bits)
    }
}

/// Serial settings of one line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SerialSettings {
    /// Baud rate; the C-863 default is 115200.
    pub baud: u32,
    /// Character framing; the C-863 uses 8N1.
    pub framing: Framing,
}

impl Default for SerialSettings {
    fn default() -> Self {
        Self {
            baud: 115_200,
            framing: Framing::default(),
        }
    }
}

/// Opens a serial device by path with `tokio-serial`, no flow control,
/// exclusive access (a second program on the same line would steal answers).
///
/// The path is reopened on every reconnect, so a symlink re-pointed to a new
/// device (udev rules, the simulator) is followed.
#[derive(Debug, Clone)]
pub struct SerialConnector {
    path: PathBuf,
    settings: SerialSettings,
}

impl SerialConnector {
    /// A connector for `path` with `settings`.
    pub fn new(path: impl Into<PathBuf>, settings: SerialSettings) -> Self {
        Self {
            path: path.into(),
            settings,
        }
    }

    /// The device path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Connector for SerialConnector {
    type Io = tokio_serial::SerialStream;

    async fn connect(&mut self) -> Result<Self::Io, DriverError> {
        let path = self.path.clone();
        let Some(path_str) = path.to_str().map(str::to_owned) else {
            return Err(DriverError::Invalid(format!(
                "device path {} is not valid UTF-8",
                path.display()
            )));
        };
        let f = self.settings.framing;
        let builder = tokio_serial::new(path_str, self.settings.baud)
            .data_bits(match f.data_bits {
                5 => tokio_serial::DataBits::Five,
                6 => tokio_serial::DataBits::Six,
                7 => tokio_serial::DataBits::Seven,
                _ => tokio_serial::DataBits::Eight,
            })
            .parity(match f.parity {
                'E' => tokio_serial::Parity::Even,
                'O' => tokio_serial::Parity::Odd,
                _ => tokio_serial::Parity::None,
            })
            .stop_bits(if f.stop_bits == 2 {
                tokio_serial::StopBits::Two
            } else {
                tokio_serial::StopBits::One
            })
            .flow_control(tokio_serial::FlowControl::None);
        // open(2) and the termios ioctls are quick, but a misbehaving USB
        // adapter can stall them: keep them off the async worker threads.
        let opened =
            tokio::task::spawn_blocking(move || tokio_serial::SerialStream::open(&builder))
                .await
                .map_err(|e| DriverError::Open {
                    path: path.clone(),
                    reason: format!("open task failed: {e}"),
                })?;
        opened.map_err(|e| {
            let missing = matches!(
                e.kind(),
                tokio_serial::ErrorKind::NoDevice
                    | tokio_serial::ErrorKind::Io(std::io::ErrorKind::NotFound)
            ) || !path.exists();
            if missing {
                DriverError::NoDevice {
                    path: path.clone(),
                    reason: e.to_string(),
                }
            } else {
                DriverError::Open {
                    path: path.clone(),
                    reason: e.to_string(),
                }
            }
        })
    }

    fn name(&self) -> String {
        self.path.display().to_string()
    }
}

/// A byte stream of any kind, boxed: what a [`LinkOpener`] returns.
pub trait LinkIo: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> LinkIo for T {}

/// A boxed future of an opened link.
pub type OpenFuture =
    std::pin::Pin<Box<dyn Future<Output = Result<Box<dyn LinkIo>, DriverError>> + Send + 'static>>;

/// Opens lines by their configured port path, for a caller that brings its
/// own byte streams instead of serial devices.
///
/// Why an object-safe trait next to [`Connector`]: [`Connector`] is generic
/// (its stream type is static), which is right for the driver but cannot be
/// stored in the daemon's configuration. The simulator's in-process rig
/// hands the daemon a `LinkOpener` whose streams are served by simulated
/// controllers on the daemon's own runtime, so a virtual clock sees every
/// byte in flight (see `hil-sim`'s virtual mode).
pub trait LinkOpener: Send + Sync + std::fmt::Debug {
    /// Opens (or reopens, after a fault) the line configured as `port`.
    fn open(&self, port: &Path) -> OpenFuture;
}

/// A [`Connector`] over a [`LinkOpener`] and one port path.
#[derive(Debug, Clone)]
pub struct OpenerConnector {
    opener: std::sync::Arc<dyn LinkOpener>,
    port: PathBuf,
}

impl OpenerConnector {
    /// A connector for `port` through `opener`.
    pub fn new(opener: std::sync::Arc<dyn LinkOpener>, port: impl Into<PathBuf>) -> Self {
        Self {
            opener,
            port: port.into(),
        }
    }
}

impl Connector for OpenerConnector {
    type Io = Box<dyn LinkIo>;

    fn connect(&mut self) -> impl Future<Output = Result<Self::Io, DriverError>> + Send {
        self.opener.open(&self.port)
    }

    fn name(&self) -> String {
        self.port.display().to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_parses_and_prints() {
        let f: Framing = "7e2".parse().unwrap();
        assert_eq!((f.data_bits, f.parity, f.stop_bits), (7, 'E', 2));
        assert_eq!(f.to_string(), "7E2");
        assert_eq!(Framing::default().to_string(), "8N1");
        for bad in ["", "8N", "9N1", "8X1", "8N3", "8N1x", "é1"] {
            assert!(bad.parse::<Framing>().is_err(), "{bad}");
        }
    }

    #[tokio::test]
    async fn missing_device_is_no_device() {
        let mut c = SerialConnector::new("/nonexistent/micropos-tty", SerialSettings::default());
        match c.connect().await {
            Err(DriverError::NoDevice { path, .. }) => {
                assert_eq!(path, PathBuf::from("/nonexistent/micropos-tty"))
            }
            other => panic!("{other:?}"),
        }
    }
}
