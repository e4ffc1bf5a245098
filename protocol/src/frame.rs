//! Depth frames: what a camera driver publishes, and what a detect request may carry inline.

use iceoryx2::prelude::ZeroCopySend;

use crate::{text, ProtocolError, CAMERA_NAME_BYTES, PROTOCOL_VERSION};

/// Pinhole intrinsics in pixels, OpenCV convention (x right, y down, z forward; pixel centres at
/// integer coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("ppfd::Intrinsics")]
#[repr(C)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// The LM-O (Kinect v1) camera, 640×480 (digits as the dataset gives them).
    #[allow(clippy::excessive_precision)]
    pub const LMO: Intrinsics = Intrinsics {
        fx: 572.4114,
        fy: 573.57043,
        cx: 325.2611,
        cy: 242.04899,
    };

    /// The shortest focal length accepted, pixels: at 1 pixel a 640-pixel image spans 179.6°.
    pub const MIN_FOCAL_PX: f32 = 1.0;
    /// The longest focal length accepted, pixels: 10⁶ pixels is a 0.04° field of view at 640
    /// pixels, far beyond any depth sensor.
    pub const MAX_FOCAL_PX: f32 = 1.0e6;

    /// Refuses focal lengths outside [`Self::MIN_FOCAL_PX`]..=[`Self::MAX_FOCAL_PX`] (zero,
    /// negative, not finite, or a value in the wrong unit) and non-finite principal points.
    /// [`Self::validate_for`] checks the principal point against the image too.
    pub fn validate(&self) -> Result<(), ProtocolError> {
        let focal_ok = |f: f32| (Self::MIN_FOCAL_PX..=Self::MAX_FOCAL_PX).contains(&f);
        if !focal_ok(self.fx) || !focal_ok(self.fy) || !self.cx.is_finite() || !self.cy.is_finite()
        {
            return Err(ProtocolError::InvalidIntrinsics(*self));
        }
        Ok(())
    }

    /// [`Self::validate`], and a principal point within the image widened by its own size on
    /// each side (a cropped image's centre may lie outside it, not a frame's width away).
    pub fn validate_for(&self, width: u32, height: u32) -> Result<(), ProtocolError> {
        self.validate()?;
        let within = |c: f32, size: u32| (-(size as f32)..=2.0 * size as f32).contains(&c);
        if !within(self.cx, width) || !within(self.cy, height) {
            return Err(ProtocolError::InvalidIntrinsics(*self));
        }
        Ok(())
    }
}

/// The user header of a depth frame on `ppfd/camera/<name>/depth`. The payload is a `[u16]`
/// slice of `width × height` raw depth values, row-major; raw × `depth_scale_mm` is the depth
/// (z) in millimetres, 0 means no measurement.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::FrameHeader")]
#[repr(C)]
pub struct FrameHeader {
    /// [`PROTOCOL_VERSION`] of the writer.
    pub protocol_version: u32,
    /// A number the driver chooses for its camera (for logs; the name is what requests use).
    pub camera_id: u32,
    /// Camera name, NUL-padded UTF-8 (see [`FrameHeader::camera_name`]): the name the frame is
    /// published under, or empty; the daemon refuses a camera's frame that names another.
    pub camera_name: [u8; CAMERA_NAME_BYTES],
    /// Frame counter of the driver, increasing by one per published frame.
    pub sequence: u64,
    /// When the sensor captured the frame: `CLOCK_MONOTONIC`, nanoseconds
    /// ([`crate::clock::monotonic_now_ns`]); 0 when unknown, for inline frames only (a camera's
    /// frame needs it for the stale check). The daemon refuses a frame stamped more than 0.1 s
    /// ahead of its own clock (wall-clock time, say): its age could not be told.
    pub capture_time_ns: u64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Camera intrinsics, pixels.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit (BOP's `depth_scale`; 1.0 for a sensor that reports mm).
    pub depth_scale_mm: f32,
    /// Zero.
    pub reserved: u32,
}

impl Default for FrameHeader {
    fn default() -> Self {
        FrameHeader {
            protocol_version: PROTOCOL_VERSION,
            camera_id: 0,
            camera_name: [0; CAMERA_NAME_BYTES],
            sequence: 0,
            capture_time_ns: 0,
            width: 0,
            height: 0,
            intrinsics: Intrinsics::default(),
            depth_scale_mm: 1.0,
            reserved: 0,
        }
    }
}

impl FrameHeader {
    /// The camera name as text.
    pub fn camera_name(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.camera_name)
    }

    /// Number of depth values the payload must hold: `width × height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Checks the header against its payload length: version, positive size, the payload holds
    /// exactly `width × height` values, usable intrinsics and depth scale.
    pub fn validate(&self, payload_len: usize) -> Result<(), ProtocolError> {
        crate::check_version(self.protocol_version)?;
        if self.width == 0 || self.height == 0 {
            return Err(ProtocolError::FrameSize {
                width: self.width,
                height: self.height,
                values: payload_len,
            });
        }
        if self.pixel_count() != payload_len {
            return Err(ProtocolError::FrameSize {
                width: self.width,
                height: self.height,
                values: payload_len,
            });
        }
        self.intrinsics.validate_for(self.width, self.height)?;
        if !(self.depth_scale_mm.is_finite() && self.depth_scale_mm > 0.0) {
            return Err(ProtocolError::InvalidDepthScale(self.depth_scale_mm));
        }
        Ok(())
    }
}

impl FrameHeader {
    /// Refuses a frame of more than `max_pixels` pixels (the daemon's `max_frame_pixels`): a
    /// detection's memory grows with the frame.
    pub fn check_pixels(&self, max_pixels: u64) -> Result<(), ProtocolError> {
        if self.pixel_count() as u64 > max_pixels {
            return Err(ProtocolError::FrameTooLarge {
                width: self.width,
                height: self.height,
                max_pixels,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vga() -> FrameHeader {
        FrameHeader {
            width: 640,
            height: 480,
            intrinsics: Intrinsics::LMO,
            camera_name: text::encode_name("camera", "kinect").unwrap(),
            ..FrameHeader::default()
        }
    }

    #[test]
    fn layout_is_fixed() {
        assert_eq!(std::mem::size_of::<Intrinsics>(), 16);
        assert_eq!(std::mem::size_of::<FrameHeader>(), 88);
        assert_eq!(std::mem::align_of::<FrameHeader>(), 8);
        assert_eq!(std::mem::offset_of!(FrameHeader, protocol_version), 0);
    }

    #[test]
    fn a_good_frame_header_passes() {
        vga().validate(640 * 480).unwrap();
        assert_eq!(vga().camera_name(), "kinect");
    }

    #[test]
    fn a_frame_without_pixels_says_so() {
        let e = FrameHeader { width: 0, ..vga() }.validate(0).unwrap_err();
        assert_eq!(
            e.to_string(),
            "depth frame 0x480 has no pixels: its width and height must be at least 1"
        );
    }

    #[test]
    fn size_mismatch_is_refused_with_both_numbers() {
        let e = vga().validate(1024).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("640x480") && m.contains("307200") && m.contains("1024"),
            "{m}"
        );
    }

    #[test]
    fn zero_nan_intrinsics_and_bad_scale_are_refused() {
        let mut h = vga();
        h.intrinsics.fx = 0.0;
        assert!(matches!(
            h.validate(640 * 480),
            Err(ProtocolError::InvalidIntrinsics(_))
        ));
        h.intrinsics.fx = f32::NAN;
        assert!(matches!(
            h.validate(640 * 480),
            Err(ProtocolError::InvalidIntrinsics(_))
        ));
        let mut h = vga();
        h.intrinsics.cy = f32::INFINITY;
        assert!(h.validate(640 * 480).is_err());
        // Finite but impossible: the pose would come out ~10³⁰ mm away, or the focal length
        // in the wrong unit would be blamed on the depth.
        for (fx, cx) in [(1.0e30, 320.0), (f32::MIN_POSITIVE, 320.0), (0.5, 320.0)]
            .into_iter()
            .chain([(500.0, 1.0e30), (500.0, -641.0), (500.0, 1281.0)])
        {
            let mut h = vga();
            (h.intrinsics.fx, h.intrinsics.cx) = (fx, cx);
            assert!(
                matches!(
                    h.validate(640 * 480),
                    Err(ProtocolError::InvalidIntrinsics(_))
                ),
                "fx {fx}, cx {cx}"
            );
        }
        // A cropped image's principal point may lie outside it.
        let mut h = vga();
        (h.intrinsics.cx, h.intrinsics.cy) = (-300.0, 900.0);
        assert!(h.validate(640 * 480).is_ok());
        let mut h = vga();
        h.depth_scale_mm = 0.0;
        assert!(matches!(
            h.validate(640 * 480),
            Err(ProtocolError::InvalidDepthScale(_))
        ));
    }

    #[test]
    fn a_frame_beyond_the_pixel_limit_is_refused_naming_the_limit() {
        let mut h = vga();
        h.check_pixels(crate::DEFAULT_MAX_FRAME_PIXELS as u64)
            .unwrap();
        h.width = 8000;
        h.height = 6000;
        let e = h
            .check_pixels(crate::DEFAULT_MAX_FRAME_PIXELS as u64)
            .unwrap_err();
        assert_eq!(e.status(), crate::detect::Status::InvalidFrame);
        let m = e.to_string();
        assert!(
            m.contains("8000x6000")
                && m.contains("48000000")
                && m.contains(&crate::DEFAULT_MAX_FRAME_PIXELS.to_string())
                && m.contains("--max-frame-pixels"),
            "{m}"
        );
    }

    #[test]
    fn wrong_version_is_refused() {
        let mut h = vga();
        h.protocol_version = PROTOCOL_VERSION + 1;
        assert!(matches!(
            h.validate(640 * 480),
            Err(ProtocolError::Version { .. })
        ));
    }
}
