//! The simulated camera served as a GigE Vision camera (feature `genicam`).
//!
//! Why: micropos's GenICam source (`micropos::camera::genicam`, over
//! aravis) is what a lab uses with a real GigE camera; serving the
//! simulator through the same protocol lets that path — discovery, GVCP
//! register access, GVSP streaming, buffer pool, pixel conversion — run end
//! to end against frames whose ground truth is known.
//!
//! How: aravis ships a GigE Vision camera simulator, `ArvGvFakeCamera`
//! (what `arv-fake-gv-camera-0.8` runs), which answers discovery and GVCP on
//! an interface (here 127.0.0.1, UDP port 3956) and streams GVSP frames.
//! Each frame is filled by a callback ([`ffi`], the only `unsafe` in
//! hil-sim); ours renders the platform's current pose with the simulated
//! camera's renderer ([`SimCamera::render_now`]) and packs it into the
//! buffer in the pixel format the client chose.
//!
//! Contract:
//! - Geometry: `Width` × `Height` start at the rig's `[camera]` size
//!   (default 1024 × 768); a smaller region set by the client is cut from
//!   the rendered frame at `OffsetX`/`OffsetY` (the decoded position then
//!   refers to that region's centre, as on a real camera).
//! - Pixel format: starts as Mono8 when `camera.bit_depth` = 8, else Mono16.
//!   Mono8 keeps the top 8 of the sensor's bits; Mono16 puts the sensor's
//!   bits at the top of 16 (a 10-bit value v is sent as v·64), little
//!   endian, as GenICam's Mono16 is defined. Other formats: the frame is
//!   black and the failure is counted ([`GigeStats`]).
//! - Timing: frames follow wall time at `AcquisitionFrameRate` (starts at
//!   `camera.fps`; aravis's thread sleeps to each frame slot); each frame
//!   integrates the rig's truth over the exposure that ends at the
//!   simulated time of its fill (no frame-slot bookkeeping and no clock
//!   advance, unlike the socket camera's grab: a free-running camera does
//!   not drive the rig's clock).
//! - Timestamps: each frame's GVSP leader carries its stamp (exposure
//!   mid-point + `camera.latency_us` + jitter) on the camera's own clock,
//!   `camera.clock_offset_s` ahead of the rig's and `camera.clock_rate_ppm`
//!   fast, in ns (the fake camera's `GevTimestampTickFrequency` is 1 GHz):
//!   a client must map it onto its own clock, as with a real camera
//!   ([`ServedFrame`] keeps both for tests).
//! - Exposure and gain: the rig's `[camera]` grey levels hold at its
//!   configured `exposure_us` and 0 dB. A client's `ExposureTime` scales
//!   the collected signal (and with it the shot noise), its `Gain` (whole
//!   dB, the fake camera's `GainRaw`) amplifies signal and noise alike;
//!   the sensor saturates at full scale ([`super::SensorSettings`]).
//!   A render slower than the frame period lowers the frame rate.
//! - Faults: `garbage` serves undecodable frames; `stall` blocks the
//!   camera's thread (no frames *and* no control answers, as a hung camera)
//!   until the mode changes or the camera stops.
//! - One GigE Vision camera per host interface: the GVCP port is fixed, so
//!   a second server on the same address fails to start (an error, with
//!   the reason).

mod ffi;

use super::{CameraMode, SensorSettings, SimCamera};
use crate::rig::RigTruth;
use aravis::prelude::*;
use micropos::frame::{Frame, Pixels};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Interface the camera listens on unless told otherwise.
pub const DEFAULT_INTERFACE: &str = "127.0.0.1";
/// Serial number unless told otherwise.
pub const DEFAULT_SERIAL: &str = "HILSIM01";

/// GenICam pixel format codes (PFNC) this camera serves.
pub const PFNC_MONO8: u32 = 0x0108_0001;
/// See [`PFNC_MONO8`].
pub const PFNC_MONO16: u32 = 0x0110_0007;

// Registers of aravis's fake camera (arvfakecamera.h, "keep in sync with
// arv-fake-camera.xml"): the features the GenICam XML maps onto them.
const REG_WIDTH: u32 = 0x100;
const REG_HEIGHT: u32 = 0x104;
const REG_SENSOR_HEIGHT: u32 = 0x118;
const REG_SENSOR_WIDTH: u32 = 0x11c;
const REG_EXPOSURE_US: u32 = 0x120;
const REG_PIXEL_FORMAT: u32 = 0x128;
const REG_FRAME_PERIOD_US: u32 = 0x138;

/// How long discovery may take to list the camera after it started.
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(5);

/// Why the GigE Vision camera could not be served.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GigeError {
    /// The serial number is not usable as a GigE Vision serial.
    #[error("serial number {0:?}: use 1 to 15 ASCII letters, digits, '-' or '_'")]
    BadSerial(String),
    /// The interface name is empty or not printable.
    #[error("interface {0:?}: give an interface name or IPv4 address (e.g. 127.0.0.1)")]
    BadInterface(String),
    /// The rendered frame does not fit the fake camera's sensor.
    #[error(
        "camera {width}×{height} px exceeds aravis's fake sensor ({max_width}×{max_height} px)"
    )]
    Geometry {
        /// Configured width, px.
        width: usize,
        /// Configured height, px.
        height: usize,
        /// Sensor width, px.
        max_width: u32,
        /// Sensor height, px.
        max_height: u32,
    },
    /// aravis refused a register write.
    #[error("aravis fake camera refused {value} in register 0x{register:03x} ({what})")]
    Register {
        /// Register address.
        register: u32,
        /// Value written.
        value: u32,
        /// Feature it backs.
        what: &'static str,
    },
    /// The fake camera did not start listening.
    #[error("the GigE Vision fake camera did not start on {interface}: {why}")]
    NotRunning {
        /// Interface asked for.
        interface: String,
        /// The likely reason.
        why: String,
    },
}

/// Where and as what to serve.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GigeConfig {
    /// Interface name or IPv4 address to listen on.
    pub interface: String,
    /// Serial number (part of the device id clients open).
    pub serial: String,
}

impl Default for GigeConfig {
    fn default() -> Self {
        Self {
            interface: DEFAULT_INTERFACE.into(),
            serial: DEFAULT_SERIAL.into(),
        }
    }
}

/// How many served frames [`GigeStats::recent`] keeps.
pub const RECENT_FRAMES: usize = 512;

/// One frame the camera filled, with the truth it shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServedFrame {
    /// aravis's frame id (GVSP block id) of the frame.
    pub frame_id: u64,
    /// The rig's ground truth the frame was rendered from.
    pub truth: RigTruth,
    /// The exposure and gain the frame was rendered with (the client's
    /// `ExposureTime` and `Gain` at that frame).
    pub sensor: SensorSettings,
    /// The frame's stamp on the rig clock (exposure mid-point + latency +
    /// jitter), simulated s.
    pub stamp_s: f64,
    /// The same stamp on the camera's own clock, as sent in the frame's
    /// GVSP leader, ns (`CameraConfig::camera_clock_ns`).
    pub camera_ns: u64,
}

/// What the camera has served so far (ground truth for tests and logs).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GigeStats {
    /// Frames filled with a rendered image.
    pub frames: u64,
    /// Frames that could not be rendered or packed (sent black).
    pub failures: u64,
    /// The last frame rendered.
    pub last: Option<ServedFrame>,
    /// The last [`RECENT_FRAMES`] frames rendered, oldest first (to pair a
    /// client's frames with their truth and stamps).
    pub recent: std::collections::VecDeque<ServedFrame>,
    /// Why the last failure happened.
    pub last_error: Option<String>,
    /// Wall time from the first to the last rendered frame, s.
    pub span_s: f64,
}

impl GigeStats {
    /// Frames per wall second over the served span (0 with < 2 frames).
    pub fn frame_rate_hz(&self) -> f64 {
        if self.frames >= 2 && self.span_s > 0.0 {
            (self.frames - 1) as f64 / self.span_s
        } else {
            0.0
        }
    }
}

#[derive(Debug, Default)]
struct StatsCell {
    stats: GigeStats,
    first: Option<Instant>,
}

fn lock(m: &Mutex<StatsCell>) -> MutexGuard<'_, StatsCell> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The running GigE Vision camera; dropping it stops serving.
pub struct GigeCamera {
    hook: Option<ffi::FillHook>,
    gv: Option<aravis::GvFakeCamera>,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<StatsCell>>,
    device_id: String,
    interface: String,
}

impl std::fmt::Debug for GigeCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GigeCamera")
            .field("device_id", &self.device_id)
            .field("interface", &self.interface)
            .finish_non_exhaustive()
    }
}

fn check_serial(serial: &str) -> Result<(), GigeError> {
    let ok = (1..=15).contains(&serial.len())
        && serial
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if ok {
        Ok(())
    } else {
        Err(GigeError::BadSerial(serial.into()))
    }
}

fn write_reg(
    fake: &aravis::FakeCamera,
    register: u32,
    value: u32,
    what: &'static str,
) -> Result<(), GigeError> {
    if fake.write_register(register, value) {
        Ok(())
    } else {
        Err(GigeError::Register {
            register,
            value,
            what,
        })
    }
}

/// Why a GV fake camera is not running: loopback/interface trouble or the
/// GVCP port taken by another camera.
fn diagnose_not_running(interface: &str) -> String {
    let addr = if interface.parse::<std::net::Ipv4Addr>().is_ok() {
        interface
    } else {
        return "aravis could not listen there (unknown interface name, or UDP port 3956 taken by another GigE Vision camera on this host)".into();
    };
    if let Err(e) = std::net::UdpSocket::bind((addr, 0)) {
        return format!("cannot open a UDP socket on {addr}: {e}");
    }
    match std::net::UdpSocket::bind((addr, 3956)) {
        Err(e) => format!(
            "UDP port 3956 (GVCP) on {addr} is not free ({e}): another GigE Vision camera (e.g. arv-fake-gv-camera-0.8) is probably running"
        ),
        Ok(_) => "aravis reported no error (run with ARV_DEBUG=all for its log)".into(),
    }
}

/// Looks the camera up through aravis's GigE Vision discovery, as a client
/// would, and returns its device id.
fn discover(serial: &str) -> Option<String> {
    let iface = aravis::GvInterface::instance()?;
    let deadline = Instant::now() + DISCOVERY_TIMEOUT;
    loop {
        iface.update_device_list();
        let found = (0..iface.n_devices()).find_map(|i| {
            let s = iface.device_serial_nbr(i)?;
            (s.as_str() == serial)
                .then(|| iface.device_id(i).map(|d| d.to_string()))
                .flatten()
        });
        if found.is_some() || Instant::now() >= deadline {
            return found;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

impl GigeCamera {
    /// Serves `camera` as a GigE Vision camera on `cfg.interface`, and
    /// returns once aravis's own discovery lists it. Clients open it by
    /// address: `micropos camera grab --source genicam:127.0.0.1`. Blocks
    /// for up to a few seconds (discovery); call it from a plain thread or
    /// `spawn_blocking`.
    pub fn start(camera: Arc<SimCamera>, cfg: &GigeConfig) -> Result<GigeCamera, GigeError> {
        check_serial(&cfg.serial)?;
        if cfg.interface.is_empty() || !cfg.interface.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(GigeError::BadInterface(cfg.interface.clone()));
        }
        let cam_cfg = camera.config();
        let gv = aravis::GvFakeCamera::new_full(Some(&cfg.interface), Some(&cfg.serial), None);
        if !gv.is_running() {
            return Err(GigeError::NotRunning {
                interface: cfg.interface.clone(),
                why: diagnose_not_running(&cfg.interface),
            });
        }
        let fake = gv.fake_camera().ok_or_else(|| GigeError::NotRunning {
            interface: cfg.interface.clone(),
            why: "aravis gave no fake camera object".into(),
        })?;
        let max_width = fake.read_register(REG_SENSOR_WIDTH).unwrap_or(0);
        let max_height = fake.read_register(REG_SENSOR_HEIGHT).unwrap_or(0);
        let (width, height) = match (u32::try_from(cam_cfg.width), u32::try_from(cam_cfg.height)) {
            (Ok(w), Ok(h)) if w <= max_width && h <= max_height => (w, h),
            _ => {
                return Err(GigeError::Geometry {
                    width: cam_cfg.width,
                    height: cam_cfg.height,
                    max_width,
                    max_height,
                })
            }
        };
        let format = if cam_cfg.bit_depth <= 8 {
            PFNC_MONO8
        } else {
            PFNC_MONO16
        };
        // The config is validated (fps > 0, exposure > 0): finite, positive.
        let period_us = (1e6 / cam_cfg.fps).round().clamp(1.0, f64::from(u32::MAX)) as u32;
        let exposure_us = cam_cfg.exposure_us.round().clamp(1.0, f64::from(u32::MAX)) as u32;
        write_reg(&fake, REG_WIDTH, width, "Width")?;
        write_reg(&fake, REG_HEIGHT, height, "Height")?;
        write_reg(&fake, REG_PIXEL_FORMAT, format, "PixelFormat")?;
        write_reg(
            &fake,
            REG_FRAME_PERIOD_US,
            period_us,
            "AcquisitionFrameRate",
        )?;
        write_reg(&fake, REG_EXPOSURE_US, exposure_us, "ExposureTime")?;

        let stop = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(Mutex::new(StatsCell::default()));
        let fill = {
            let stop = stop.clone();
            let stats = stats.clone();
            move |req: ffi::FillRequest<'_>| fill_frame(&camera, &stop, &stats, req)
        };
        let hook = ffi::FillHook::install(fake, Box::new(fill));
        let mut served = GigeCamera {
            hook: Some(hook),
            gv: Some(gv),
            stop,
            stats,
            device_id: String::new(),
            interface: cfg.interface.clone(),
        };
        served.device_id = discover(&cfg.serial).ok_or_else(|| GigeError::NotRunning {
            interface: cfg.interface.clone(),
            why: format!(
                "the camera runs but aravis's GigE Vision discovery did not list serial {} within {} s",
                cfg.serial,
                DISCOVERY_TIMEOUT.as_secs()
            ),
        })?;
        tracing::info!(
            "simulated camera served as GigE Vision camera {} on {}",
            served.device_id,
            served.interface
        );
        Ok(served)
    }

    /// The aravis device id discovery lists (`Aravis-Fake-SERIAL`). Clients
    /// in other processes should open the camera by its address
    /// ([`GigeCamera::interface`], `genicam:127.0.0.1`): on a host with
    /// other interfaces, aravis may discover the loopback camera through
    /// one of them and then stream to an address the camera cannot reach
    /// (seen here: interface 192.0.2.2, no frames).
    pub fn device_id(&self) -> &str {
        &self.device_id
    }

    /// The interface served on.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// What has been served so far.
    pub fn stats(&self) -> GigeStats {
        lock(&self.stats).stats.clone()
    }

    /// Stops serving (same as dropping).
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        // A stalled fill returns when it sees the flag; then the hook can
        // take aravis's fill mutex, and the camera's thread can be joined.
        self.stop.store(true, Ordering::SeqCst);
        self.hook = None;
        self.gv = None;
    }
}

impl Drop for GigeCamera {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The fill callback's body (on aravis's GV camera thread): renders the
/// frame, packs it, and returns its stamp on the camera's clock (`None` for
/// a frame sent black: aravis's host stamp stays).
fn fill_frame(
    camera: &SimCamera,
    stop: &AtomicBool,
    stats: &Mutex<StatsCell>,
    req: ffi::FillRequest<'_>,
) -> Option<u64> {
    while camera.mode() == CameraMode::Stall && !stop.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(20));
    }
    if stop.load(Ordering::SeqCst) {
        return None;
    }
    let cfg = camera.config();
    let sensor = sensor_settings(&req, cfg.exposure_us);
    let result = camera
        .render_now(Some(sensor))
        .map_err(|e| e.to_string())
        .and_then(|grab| {
            pack_region(
                &grab.frame,
                req.pixel_format,
                req.offset,
                [req.width, req.height],
                req.data,
            )?;
            Ok((grab.truth, grab.frame.timestamp_s))
        });
    let mut cell = lock(stats);
    match result {
        Ok((truth, stamp_s)) => {
            let camera_ns = cfg.camera_clock_ns(stamp_s);
            let now = Instant::now();
            let first = *cell.first.get_or_insert(now);
            cell.stats.frames += 1;
            cell.stats.span_s = now.duration_since(first).as_secs_f64();
            let served = ServedFrame {
                frame_id: req.frame_id,
                truth,
                sensor,
                stamp_s,
                camera_ns,
            };
            cell.stats.last = Some(served);
            if cell.stats.recent.len() == RECENT_FRAMES {
                cell.stats.recent.pop_front();
            }
            cell.stats.recent.push_back(served);
            Some(camera_ns)
        }
        Err(e) => {
            req.data.fill(0);
            cell.stats.failures += 1;
            if cell.stats.failures == 1 || cell.stats.failures % 100 == 0 {
                tracing::warn!(
                    "GigE camera frame {} sent black ({} so far): {e}",
                    req.frame_id,
                    cell.stats.failures
                );
            }
            cell.stats.last_error = Some(e);
            None
        }
    }
}

/// The sensor settings of a fill request. An exposure register of 0 (never
/// set, or a client that wrote nonsense) renders at the rig's configured
/// `exposure_us` rather than black. The fake camera's `Gain` feature is the
/// `GainRaw` register in whole dB.
fn sensor_settings(req: &ffi::FillRequest<'_>, configured_exposure_us: f64) -> SensorSettings {
    SensorSettings {
        exposure_us: if req.exposure_us > 0 {
            f64::from(req.exposure_us)
        } else {
            configured_exposure_us
        },
        gain_db: f64::from(req.gain_raw),
    }
}

/// Packs the region `size` = [w, h] at `offset` of `frame` into `out` in
/// GenICam pixel format `pixel_format` (Mono8 or Mono16, see the module
/// docs for the bit alignment). Errors say why nothing was packed.
pub fn pack_region(
    frame: &Frame,
    pixel_format: u32,
    offset: [usize; 2],
    size: [usize; 2],
    out: &mut [u8],
) -> Result<(), String> {
    let [x0, y0] = offset;
    let [w, h] = size;
    let fits = |o: usize, n: usize, max: usize| o.checked_add(n).is_some_and(|e| e <= max);
    if w == 0 || h == 0 || !fits(x0, w, frame.width()) || !fits(y0, h, frame.height()) {
        return Err(format!(
            "region {w}×{h} at ({x0}, {y0}) is not inside the {}×{} rendered frame",
            frame.width(),
            frame.height()
        ));
    }
    let bytes_pp = match pixel_format {
        PFNC_MONO8 => 1,
        PFNC_MONO16 => 2,
        other => {
            return Err(format!(
                "pixel format 0x{other:08x} is not served (Mono8 or Mono16 only)"
            ))
        }
    };
    let need = w * h * bytes_pp;
    if out.len() < need {
        return Err(format!(
            "buffer of {} bytes is smaller than the {need} bytes of a {w}×{h} frame",
            out.len()
        ));
    }
    let depth = u32::from(frame.bit_depth());
    let fw = frame.width();
    // Sample at (x, y) of the region, as a `depth`-bit value.
    let value = |x: usize, y: usize| -> u32 {
        let i = (y0 + y) * fw + x0 + x;
        match frame.pixels() {
            Pixels::U8(p) => p.get(i).copied().map_or(0, u32::from),
            Pixels::U16(p) => p.get(i).copied().map_or(0, u32::from),
        }
    };
    for y in 0..h {
        let row = &mut out[y * w * bytes_pp..(y + 1) * w * bytes_pp];
        if bytes_pp == 1 {
            let shift = depth.saturating_sub(8);
            for (x, b) in row.iter_mut().enumerate() {
                *b = u8::try_from(value(x, y) >> shift).unwrap_or(u8::MAX);
            }
        } else {
            let shift = 16u32.saturating_sub(depth);
            for (x, px) in row.chunks_exact_mut(2).enumerate() {
                let v = u16::try_from(value(x, y) << shift).unwrap_or(u16::MAX);
                px.copy_from_slice(&v.to_le_bytes());
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame10() -> Frame {
        // 4×3, 10-bit ramp.
        let p: Vec<u16> = (0..12u16).map(|i| i * 93).collect();
        Frame::new(4, 3, 10, Pixels::U16(p), 0.0, 0).unwrap()
    }

    #[test]
    fn mono16_puts_the_sensor_bits_on_top_little_endian() {
        let f = frame10();
        let mut out = vec![0u8; 24];
        pack_region(&f, PFNC_MONO16, [0, 0], [4, 3], &mut out).unwrap();
        for i in 0..12 {
            let v = u16::from_le_bytes([out[2 * i], out[2 * i + 1]]);
            assert_eq!(v, (i as u16 * 93) << 6);
        }
    }

    #[test]
    fn mono8_keeps_the_top_bits_and_regions_are_cut_at_their_offset() {
        let f = frame10();
        let mut out = vec![0u8; 4];
        pack_region(&f, PFNC_MONO8, [1, 1], [2, 2], &mut out).unwrap();
        let expect: Vec<u8> = [5u16, 6, 9, 10]
            .iter()
            .map(|i| ((i * 93) >> 2) as u8)
            .collect();
        assert_eq!(out, expect);
        let f8 = Frame::new(2, 1, 8, Pixels::U8(vec![7, 250]), 0.0, 0).unwrap();
        let mut out = vec![0u8; 4];
        pack_region(&f8, PFNC_MONO16, [0, 0], [2, 1], &mut out).unwrap();
        assert_eq!(out, [0, 7, 0, 250]);
    }

    #[test]
    fn bad_regions_formats_and_buffers_are_errors() {
        let f = frame10();
        let mut out = vec![0u8; 64];
        let e = pack_region(&f, PFNC_MONO8, [3, 0], [2, 1], &mut out).unwrap_err();
        assert!(e.contains("not inside"), "{e}");
        let e = pack_region(&f, PFNC_MONO8, [usize::MAX, 0], [2, 1], &mut out).unwrap_err();
        assert!(e.contains("not inside"), "{e}");
        let e = pack_region(&f, 0x0218_0014, [0, 0], [4, 3], &mut out).unwrap_err();
        assert!(e.contains("not served"), "{e}");
        let e = pack_region(&f, PFNC_MONO16, [0, 0], [4, 3], &mut out[..23]).unwrap_err();
        assert!(e.contains("smaller"), "{e}");
    }

    #[test]
    fn serials_are_checked() {
        assert!(check_serial("HILSIM01").is_ok());
        for bad in ["", "has space", "1234567890123456", "é"] {
            assert!(check_serial(bad).is_err(), "{bad:?}");
        }
    }
}
