//! The one piece of aravis the Rust bindings do not wrap: installing a
//! frame-fill callback on an `ArvFakeCamera`
//! (`arv_fake_camera_set_fill_pattern`), and reading the buffer it hands
//! the callback. This is the only `unsafe` code in hil-sim.
//!
//! How aravis uses it (0.8, `arvfakecamera.c`): the GV fake camera's single
//! thread, once per frame period, calls `arv_fake_camera_fill_buffer`,
//! which sets the buffer's geometry, pixel format, frame id and timestamp
//! from the camera's registers and then, *under the camera's fill mutex*,
//! calls the installed callback with the buffer, the user data pointer,
//! the exposure (µs), the raw gain and the pixel format (exposure and gain
//! are not used: the simulated image does not depend on them). The thread then
//! sends the buffer's bytes as GVSP packets, with the buffer's timestamp in
//! the leader (which the callback may set: aravis set it before the call). `set_fill_pattern` takes the
//! same mutex, and `NULL` restores aravis's own diagonal ramp.
//!
//! The buffer's size: in aravis 0.8 `arv_buffer_get_data` reports the
//! *received* size, which is 0 while the fake camera fills (its own
//! patterns set the private `received_size`; no public setter exists, and
//! the GV camera sends the full payload regardless). What the callback may
//! write is the camera's payload, `arv_fake_camera_get_payload` (width ×
//! height × bytes per pixel from its registers): `fill_buffer` returns
//! early with `SIZE_MISMATCH` *before* calling the callback unless the
//! buffer's allocation holds that payload, and the registers cannot change
//! during the callback (the GV camera's one thread, which applies GVCP
//! register writes, is the thread running it; hil-sim writes registers only
//! before installing the hook).
//!
//! Invariants this module keeps:
//! - the user data is a leaked `Box<Context>`, freed only in
//!   [`FillHook`]'s `Drop`, *after* `set_fill_pattern(NULL)` returned: that
//!   call waits for a running callback (same mutex), and no later call can
//!   see the pointer;
//! - the callback never unwinds into C: everything runs in `catch_unwind`;
//! - the closure sees the pixel bytes only as a `&mut [u8]` of the payload
//!   size (see above).

#![allow(unsafe_code)]

use aravis::glib::translate::ToGlibPtr;
use aravis_sys::{ArvBuffer, ArvPixelFormat};
use std::ffi::c_void;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Mutex;

/// What the fill callback gets: one frame buffer to fill, as aravis set it
/// up from the camera's registers.
#[derive(Debug)]
pub struct FillRequest<'a> {
    /// Image width, px (the camera's `Width`).
    pub width: usize,
    /// Image height, px (the camera's `Height`).
    pub height: usize,
    /// Region offset on the sensor, px (`OffsetX`, `OffsetY`).
    pub offset: [usize; 2],
    /// GenICam pixel format code (PFNC), e.g. 0x01080001 = Mono8.
    pub pixel_format: u32,
    /// Frame id aravis gave this frame (GVSP block id).
    pub frame_id: u64,
    /// The camera's `ExposureTime` register at this frame, µs.
    pub exposure_us: u32,
    /// The camera's `GainRaw` register at this frame (the fake camera's
    /// `Gain` feature writes it in whole dB).
    pub gain_raw: u32,
    /// The frame's bytes (the payload aravis sends: width × height × bytes
    /// per pixel).
    pub data: &'a mut [u8],
}

/// The closure that fills frames (runs on aravis's GV camera thread). It
/// returns the frame's timestamp on the camera's clock, ns, which replaces
/// the one aravis set (the host's real time at the fill): the GV camera
/// thread puts the buffer's timestamp in the GVSP leader after the fill.
/// `None` keeps aravis's.
pub type FillFn = dyn FnMut(FillRequest<'_>) -> Option<u64> + Send;

/// What the callback's user data points to.
struct Context {
    /// The camera whose payload bounds the buffer (kept alive by the hook).
    camera: *mut aravis_sys::ArvFakeCamera,
    fill: Mutex<Box<FillFn>>,
}

/// An installed fill callback; dropping it restores aravis's default
/// pattern and frees the closure (see the module docs for why that order is
/// safe).
pub struct FillHook {
    camera: aravis::FakeCamera,
    context: *mut Context,
}

// SAFETY: `context` points to a `Context` whose closure is Send and behind
// a Mutex, and whose camera pointer is only passed to aravis (thread-safe
// GObject, kept alive by `camera`); the context is dereferenced only by the
// callback and freed only in Drop. `FakeCamera` is Send (aravis-rs).
unsafe impl Send for FillHook {}

impl std::fmt::Debug for FillHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FillHook").finish_non_exhaustive()
    }
}

impl FillHook {
    /// Installs `fill` as `camera`'s frame-fill callback.
    pub fn install(camera: aravis::FakeCamera, fill: Box<FillFn>) -> FillHook {
        let raw: *mut aravis_sys::ArvFakeCamera = camera.to_glib_none().0;
        let context: *mut Context = Box::into_raw(Box::new(Context {
            camera: raw,
            fill: Mutex::new(fill),
        }));
        // SAFETY: `raw` is a live ArvFakeCamera (we hold a reference in
        // `camera` for as long as the hook exists); `trampoline` matches
        // `ArvFakeCameraFillPattern`; `context` stays valid until Drop has
        // uninstalled the callback.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(
                raw,
                Some(trampoline),
                context.cast::<c_void>(),
            );
        }
        FillHook { camera, context }
    }
}

impl Drop for FillHook {
    fn drop(&mut self) {
        let raw: *mut aravis_sys::ArvFakeCamera = self.camera.to_glib_none().0;
        // SAFETY: `raw` is live (held by `self.camera`). With NULL aravis
        // restores its own pattern; the call takes the fill mutex, so a
        // callback running now finishes first and none starts afterwards
        // with our pointer. Only then is the context freed, exactly once
        // (it came from Box::into_raw in `install`).
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(raw, None, std::ptr::null_mut());
            drop(Box::from_raw(self.context));
        }
    }
}

fn non_negative(v: std::ffi::c_int) -> usize {
    usize::try_from(v).unwrap_or(0)
}

/// Called by aravis on the GV camera thread, under the fill mutex.
unsafe extern "C" fn trampoline(
    buffer: *mut ArvBuffer,
    user_data: *mut c_void,
    exposure_us: u32,
    gain_raw: u32,
    pixel_format: ArvPixelFormat,
) {
    if buffer.is_null() || user_data.is_null() {
        return;
    }
    // No unwinding into C, whatever the closure does.
    let _ = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: `user_data` is the `Context` installed by `FillHook`,
        // alive until the hook's Drop, which cannot run past this call (it
        // waits on the fill mutex aravis holds while calling us).
        let context = unsafe { &*user_data.cast::<Context>() };
        // SAFETY: `buffer` is the live ArvBuffer aravis is filling and
        // `context.camera` the live camera filling it; the GV camera thread
        // is blocked in fill_buffer until we return, and the buffer is
        // private to that thread, so nothing else touches it meanwhile.
        let mut received: usize = 0;
        let (data, payload, width, height, x, y, frame_id) = unsafe {
            (
                aravis_sys::arv_buffer_get_data(buffer, &mut received),
                aravis_sys::arv_fake_camera_get_payload(context.camera),
                non_negative(aravis_sys::arv_buffer_get_image_width(buffer)),
                non_negative(aravis_sys::arv_buffer_get_image_height(buffer)),
                non_negative(aravis_sys::arv_buffer_get_image_x(buffer)),
                non_negative(aravis_sys::arv_buffer_get_image_y(buffer)),
                aravis_sys::arv_buffer_get_frame_id(buffer),
            )
        };
        if data.is_null() || payload == 0 {
            return;
        }
        // SAFETY: `data` is the start of the buffer's allocation, which
        // holds at least `payload` bytes (fill_buffer checked it before
        // calling us, and the payload registers cannot change meanwhile:
        // see the module docs). Exclusive to us for this call (see above);
        // the slice does not outlive it.
        let bytes = unsafe { std::slice::from_raw_parts_mut(data, payload) };
        let mut fill = context.fill.lock().unwrap_or_else(|e| e.into_inner());
        let stamp_ns = fill(FillRequest {
            width,
            height,
            offset: [x, y],
            pixel_format,
            frame_id,
            exposure_us,
            gain_raw,
            data: bytes,
        });
        if let Some(ns) = stamp_ns {
            // SAFETY: `buffer` is live and private to this thread for the
            // call (see above); setting its timestamp is a plain field write.
            unsafe { aravis_sys::arv_buffer_set_timestamp(buffer, ns) };
        }
    }));
}
