//! GenICam cameras (GigE Vision, USB3 Vision) through aravis.
//!
//! Why aravis: it is the maintained open-source GenICam stack on Linux
//! (Debian packages it), speaks both GigE Vision and USB3 Vision, and
//! exposes the standard features (ExposureTime, Gain, PixelFormat,
//! AcquisitionFrameRate) by name, so one source serves every compliant
//! camera. Every aravis call returns a `Result`; none is unwrapped.
//!
//! Camera ids: `genicam` opens the first camera aravis finds; `genicam:ID`
//! accepts an aravis device id ("Vendor-Model-Serial"), a serial number
//! for USB3 cameras or an IP address for GigE cameras. Ids of the form
//! `Fake_N` open aravis's in-process fake camera (the "Fake" interface,
//! which aravis leaves out of its normal device lookup): handy to try the
//! CLI or the daemon without hardware, and what the integration test uses.
//!
//! Timestamps: the buffer's timestamp is the camera's own clock (a GigE
//! camera's tick counter from the GVSP leader, scaled by aravis with the
//! camera's `GevTimestampTickFrequency`); [`TimeAnchor`] makes it seconds
//! since the source opened and [`FrameSource::frame_clock`] says so, and the
//! vision pipeline maps it onto the rig clock
//! ([`super::timebase::CameraTimebase`]). A camera without timestamps
//! (stamp 0) gets the host's time. Sequence numbers follow the camera's frame ids, unwrapped, so
//! frames the camera or the network dropped leave gaps.

use std::time::Duration;

use aravis::glib;
use aravis::prelude::*;
use aravis::{AcquisitionMode, Buffer, BufferStatus, Camera, Stream};

use super::convert::to_frame;
use super::{
    unwrap_counter, CameraError, CameraInfo, CameraListing, FrameClock, FrameSource, PixelFormat,
    TimeAnchor,
};
use crate::frame::Frame;

/// Buffers queued on the stream: enough to ride out a slow decode without
/// the camera dropping frames, few enough to keep latency low.
const N_BUFFERS: usize = 8;

fn backend_err(context: &str, e: impl std::fmt::Display) -> CameraError {
    CameraError::Backend {
        backend: "genicam",
        message: format!("{context}: {e}"),
    }
}

fn to_aravis_format(format: PixelFormat) -> aravis::PixelFormat {
    match format {
        PixelFormat::Mono8 => aravis::PixelFormat::MONO_8,
        PixelFormat::Mono10 => aravis::PixelFormat::MONO_10,
        PixelFormat::Mono12 => aravis::PixelFormat::MONO_12,
        PixelFormat::Mono14 => aravis::PixelFormat::MONO_14,
        PixelFormat::Mono16 => aravis::PixelFormat::MONO_16,
        PixelFormat::Yuyv => aravis::PixelFormat::YUV_422_YUYV_PACKED,
    }
}

fn from_aravis_format(format: aravis::PixelFormat) -> Option<PixelFormat> {
    PixelFormat::ALL
        .into_iter()
        .find(|&f| to_aravis_format(f) == format)
        .or((format == aravis::PixelFormat::CUSTOM_YUV_422_YUYV_PACKED)
            .then_some(PixelFormat::Yuyv))
}

/// A GenICam camera streaming continuously into a small buffer pool.
pub struct GenicamSource {
    camera: Camera,
    stream: Option<Stream>,
    info: CameraInfo,
    timeout: Duration,
    clock: TimeAnchor,
    /// (raw frame id, sequence) of the last frame.
    last_id: Option<(u64, u64)>,
    frame_id_modulus: u64,
    /// Whether the last frame carried the camera's own timestamp.
    camera_stamped: bool,
}

impl std::fmt::Debug for GenicamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GenicamSource")
            .field("info", &self.info)
            .field("timeout", &self.timeout)
            .finish_non_exhaustive()
    }
}

/// Opens the camera `id` names (see the module docs).
fn open_camera(id: Option<&str>) -> Result<Camera, CameraError> {
    let not_found = |e: glib::Error| {
        CameraError::NoDevice {
        path: id.unwrap_or("(first GenICam camera)").to_string(),
        hint: format!(
            "aravis: {e}; check `micropos camera list`, cabling, and for GigE that the camera is on this host's subnet"
        ),
    }
    };
    match id {
        Some(fake) if fake.starts_with("Fake_") => {
            let iface = aravis::FakeInterface::instance().ok_or_else(|| CameraError::Backend {
                backend: "genicam",
                message: "aravis has no Fake interface".into(),
            })?;
            // aravis returns no device *and* no error for an unknown id here
            // (the bindings would panic on that), so check the list first.
            iface.update_device_list();
            let known =
                (0..iface.n_devices()).any(|i| iface.device_id(i).is_some_and(|d| d == fake));
            if !known {
                return Err(CameraError::NoDevice {
                    path: fake.to_string(),
                    hint: "aravis's fake interface offers only Fake_1".into(),
                });
            }
            let device = iface.open_device(Some(fake)).map_err(not_found)?;
            Camera::with_device(&device).map_err(|e| backend_err("wrapping fake device", e))
        }
        _ => Camera::new(id).map_err(not_found),
    }
}

impl GenicamSource {
    /// Opens a camera and starts continuous acquisition.
    pub fn open(id: Option<&str>) -> Result<Self, CameraError> {
        let camera = open_camera(id)?;
        let vendor = camera
            .vendor_name()
            .map(|s| s.to_string())
            .unwrap_or_default();
        let model = camera
            .model_name()
            .map_err(|e| backend_err("reading model name", e))?;
        let serial = camera
            .device_serial_number()
            .map(|s| s.to_string())
            .unwrap_or_default();
        let frame_id_modulus = if camera.is_gv_device() { 0xFFFF } else { 0 };
        let mut source = Self {
            info: CameraInfo {
                backend: "genicam",
                model: format!("{vendor} {model}").trim().to_string(),
                serial,
                width: 0,
                height: 0,
                pixel_format: String::new(),
                bit_depth: 8,
            },
            camera,
            stream: None,
            timeout: Duration::from_secs(2),
            clock: TimeAnchor::new(),
            last_id: None,
            frame_id_modulus,
            camera_stamped: false,
        };
        source.start()?;
        Ok(source)
    }

    /// Reads geometry and format, creates the stream and starts acquisition.
    fn start(&mut self) -> Result<(), CameraError> {
        let (_, _, w, h) = self
            .camera
            .region()
            .map_err(|e| backend_err("reading region", e))?;
        let format = self
            .camera
            .pixel_format()
            .map_err(|e| backend_err("reading pixel format", e))?;
        let name = self
            .camera
            .pixel_format_as_string()
            .map(|s| s.to_string())
            .unwrap_or_else(|_| format!("0x{:08x}", format.raw()));
        self.info.width = usize::try_from(w).unwrap_or(0);
        self.info.height = usize::try_from(h).unwrap_or(0);
        self.info.bit_depth = from_aravis_format(format).map_or(8, PixelFormat::bit_depth);
        self.info.pixel_format = name;
        let payload = self
            .camera
            .payload()
            .map_err(|e| backend_err("reading payload size", e))?;
        let stream = self
            .camera
            .create_stream()
            .map_err(|e| backend_err("creating stream", e))?;
        for _ in 0..N_BUFFERS {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        self.camera
            .set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(|e| backend_err("setting continuous acquisition", e))?;
        self.camera
            .start_acquisition()
            .map_err(|e| backend_err("starting acquisition", e))?;
        self.stream = Some(stream);
        Ok(())
    }

    fn stop(&mut self) -> Result<(), CameraError> {
        let result = self
            .camera
            .stop_acquisition()
            .map_err(|e| backend_err("stopping acquisition", e));
        // Dropping the stream joins its receive thread and frees the buffers.
        self.stream = None;
        result
    }

    fn sequence(&mut self, raw: u64) -> u64 {
        let seq = match self.last_id {
            None => 0,
            Some((last, seq)) => unwrap_counter(last, raw, seq, self.frame_id_modulus),
        };
        self.last_id = Some((raw, seq));
        seq
    }

    fn frame_from(&mut self, buffer: &Buffer) -> Result<Frame, CameraError> {
        let status = buffer.status();
        if status != BufferStatus::Success {
            return Err(backend_err(
                "frame not received",
                format!("buffer status {status:?} (frame id {})", buffer.frame_id()),
            ));
        }
        let aformat = buffer.image_pixel_format();
        let format = from_aravis_format(aformat).ok_or_else(|| {
            CameraError::BadData(format!(
                "pixel format {} (0x{:08x}) is not supported; set Mono8..Mono16 or YUV422_8",
                self.info.pixel_format,
                aformat.raw()
            ))
        })?;
        let width = usize::try_from(buffer.image_width())
            .map_err(|_| CameraError::BadData("negative image width".into()))?;
        let height = usize::try_from(buffer.image_height())
            .map_err(|_| CameraError::BadData("negative image height".into()))?;
        let (x_pad, _) = buffer.image_padding();
        let x_pad = usize::try_from(x_pad).unwrap_or(0);
        let stride = width * super::convert::bytes_per_pixel(format) + x_pad;
        let data = buffer.image_data();
        let ns = buffer.timestamp();
        self.camera_stamped = ns != 0;
        let ts = self
            .clock
            .stamp(self.camera_stamped.then_some(ns as f64 * 1e-9));
        let seq = self.sequence(buffer.frame_id());
        to_frame(format, width, height, stride, &data, ts, seq)
    }
}

impl Drop for GenicamSource {
    fn drop(&mut self) {
        if let Err(e) = self.stop() {
            tracing::warn!("closing camera: {e}");
        }
    }
}

impl FrameSource for GenicamSource {
    fn info(&self) -> CameraInfo {
        self.info.clone()
    }

    /// The camera's tick counter (GVSP leader, U3V trailer), when the last
    /// frame carried one.
    fn frame_clock(&self) -> FrameClock {
        if self.camera_stamped {
            FrameClock::Camera
        } else {
            FrameClock::None
        }
    }

    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        let stream = self.stream.clone().ok_or_else(|| CameraError::Backend {
            backend: "genicam",
            message: "stream is not running (a previous reconfiguration failed)".into(),
        })?;
        let timeout_us = u64::try_from(self.timeout.as_micros()).unwrap_or(u64::MAX);
        let buffer = stream
            .timeout_pop_buffer(timeout_us)
            .ok_or(CameraError::Timeout {
                timeout_s: self.timeout.as_secs_f64(),
            })?;
        let frame = self.frame_from(&buffer);
        // Whatever happened, the buffer goes back to the pool.
        stream.push_buffer(buffer);
        frame
    }

    fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    fn set_exposure_us(&mut self, exposure_us: f64) -> Result<f64, CameraError> {
        let (min, max) = self
            .camera
            .exposure_time_bounds()
            .map_err(|e| backend_err("reading exposure bounds", e))?;
        if !(exposure_us >= min && exposure_us <= max) {
            return Err(CameraError::OutOfRange {
                what: "exposure_us",
                value: exposure_us,
                min,
                max,
            });
        }
        self.camera
            .set_exposure_time(exposure_us)
            .map_err(|e| backend_err("setting exposure", e))?;
        self.exposure_us()
    }

    fn exposure_us(&self) -> Result<f64, CameraError> {
        self.camera
            .exposure_time()
            .map_err(|e| backend_err("reading exposure", e))
    }

    fn set_gain_db(&mut self, gain_db: f64) -> Result<f64, CameraError> {
        let (min, max) = self
            .camera
            .gain_bounds()
            .map_err(|e| backend_err("reading gain bounds", e))?;
        if !(gain_db >= min && gain_db <= max) {
            return Err(CameraError::OutOfRange {
                what: "gain_db",
                value: gain_db,
                min,
                max,
            });
        }
        self.camera
            .set_gain(gain_db)
            .map_err(|e| backend_err("setting gain", e))?;
        self.gain_db()
    }

    fn gain_db(&self) -> Result<f64, CameraError> {
        self.camera
            .gain()
            .map_err(|e| backend_err("reading gain", e))
    }

    fn pixel_formats(&self) -> Result<Vec<PixelFormat>, CameraError> {
        let names = self
            .camera
            .dup_available_pixel_formats_as_strings()
            .map_err(|e| backend_err("listing pixel formats", e))?;
        let mut out: Vec<PixelFormat> = names
            .iter()
            .filter_map(|n| n.as_str().parse::<PixelFormat>().ok())
            .collect();
        out.dedup();
        Ok(out)
    }

    fn set_pixel_format(&mut self, format: PixelFormat) -> Result<(), CameraError> {
        let available = self.pixel_formats()?;
        if !available.contains(&format) {
            return Err(CameraError::NotSupported {
                source_kind: "genicam",
                what: format!("pixel format {format}"),
                why: format!(
                    "the camera offers {}",
                    available
                        .iter()
                        .map(|f| f.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        // The payload size changes with the format: stop, drop the old
        // buffers, switch, and restart with buffers of the new size.
        self.stop()?;
        self.camera
            .set_pixel_format(to_aravis_format(format))
            .map_err(|e| backend_err("setting pixel format", e))?;
        self.last_id = None;
        self.start()
    }

    fn set_frame_rate_hz(&mut self, rate_hz: f64) -> Result<f64, CameraError> {
        let (min, max) = self
            .camera
            .frame_rate_bounds()
            .map_err(|e| backend_err("reading frame rate bounds", e))?;
        if !(rate_hz >= min && rate_hz <= max) {
            return Err(CameraError::OutOfRange {
                what: "frame_rate_hz",
                value: rate_hz,
                min,
                max,
            });
        }
        self.camera
            .set_frame_rate(rate_hz)
            .map_err(|e| backend_err("setting frame rate", e))?;
        self.camera
            .frame_rate()
            .map_err(|e| backend_err("reading frame rate", e))
    }
}

/// GenICam cameras visible to aravis (GigE Vision and USB3 Vision).
pub fn list() -> Result<Vec<CameraListing>, CameraError> {
    let mut out = Vec::new();
    let interfaces = [
        ("GigE Vision", aravis::GvInterface::instance()),
        ("USB3 Vision", aravis::UvInterface::instance()),
    ];
    for (protocol, iface) in interfaces {
        let Some(iface) = iface else { continue };
        iface.update_device_list();
        for i in 0..iface.n_devices() {
            let Some(id) = iface.device_id(i) else {
                continue;
            };
            let field = |v: Option<glib::GString>| v.map(|s| s.to_string()).unwrap_or_default();
            let description = format!(
                "{protocol}: {} {} serial {} at {}",
                field(iface.device_vendor(i)),
                field(iface.device_model(i)),
                field(iface.device_serial_nbr(i)),
                field(iface.device_address(i)),
            );
            out.push(CameraListing {
                backend: "genicam",
                source: format!("genicam:{id}"),
                description,
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_format_mapping_round_trips() {
        for f in PixelFormat::ALL {
            assert_eq!(from_aravis_format(to_aravis_format(f)), Some(f));
        }
        assert_eq!(from_aravis_format(aravis::PixelFormat::RGB_8_PACKED), None);
    }
}
