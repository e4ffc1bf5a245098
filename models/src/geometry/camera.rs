//! Pinhole intrinsics and depth frames, the input of scene preparation and the target of
//! rendering.

use nalgebra::{Point3, Vector2};

use crate::{Error, Result};

/// Pinhole camera intrinsics in pixels (OpenCV convention: x right, y down, z forward; pixel
/// centres at integer coordinates).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// The LM-O (Kinect v1) camera, 640×480 (digits as the dataset gives them): the embedded
    /// default for generated scenes.
    #[allow(clippy::excessive_precision)]
    pub const LMO: Intrinsics = Intrinsics {
        fx: 572.4114,
        fy: 573.57043,
        cx: 325.2611,
        cy: 242.04899,
    };

    /// The shortest focal length accepted, pixels (as the daemon's protocol,
    /// `ppfd_protocol::frame::Intrinsics`): at 1 pixel a 640-pixel image spans 179.6°.
    pub const MIN_FOCAL_PX: f32 = 1.0;
    /// The longest focal length accepted, pixels: 10⁶ pixels is a 0.04° field of view at 640
    /// pixels, far beyond any depth sensor.
    pub const MAX_FOCAL_PX: f32 = 1.0e6;

    /// Refuses focal lengths outside [`Self::MIN_FOCAL_PX`]..=[`Self::MAX_FOCAL_PX`] (zero,
    /// negative, not finite, or a value in the wrong unit) and non-finite principal points.
    /// [`Self::validate_for`] checks the principal point against the image too.
    pub fn validate(&self) -> Result<()> {
        let ok_focal = |f: f32| (Self::MIN_FOCAL_PX..=Self::MAX_FOCAL_PX).contains(&f);
        if !ok_focal(self.fx) || !ok_focal(self.fy) {
            return Err(Error::InvalidFrame(format!(
                "focal lengths must be {} to {} pixels, got fx={} fy={}",
                Self::MIN_FOCAL_PX,
                Self::MAX_FOCAL_PX,
                self.fx,
                self.fy
            )));
        }
        if !self.cx.is_finite() || !self.cy.is_finite() {
            return Err(Error::InvalidFrame(format!(
                "principal point must be finite, got cx={} cy={}",
                self.cx, self.cy
            )));
        }
        Ok(())
    }

    /// [`Self::validate`], and a principal point within the image widened by its own size on
    /// each side (a cropped image's centre may lie outside it, not a frame's width away).
    pub fn validate_for(&self, width: u32, height: u32) -> Result<()> {
        self.validate()?;
        let within = |c: f32, size: u32| (-(size as f32)..=2.0 * size as f32).contains(&c);
        if !within(self.cx, width) || !within(self.cy, height) {
            return Err(Error::InvalidFrame(format!(
                "principal point ({}, {}) lies more than the image's size outside the {width}x{height} \
                 image",
                self.cx, self.cy
            )));
        }
        Ok(())
    }

    /// Projects a camera-space point (z > 0) to pixel coordinates.
    #[inline]
    pub fn project(&self, p: &Point3<f32>) -> Vector2<f32> {
        Vector2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }

    /// The pixel a camera-space point (z > 0) falls in: [`Intrinsics::project`] rounded half
    /// away from zero, as `f32::round` does, but without its library call (baseline x86-64 has
    /// no rounding instruction; the call sat in re-scoring's and ICP's profiles).
    #[inline]
    pub fn pixel(&self, p: &Point3<f32>) -> (i64, i64) {
        let uv = self.project(p);
        let round = |x: f32| (x + 0.5f32.copysign(x)) as i64;
        (round(uv.x), round(uv.y))
    }

    /// The same camera with pixels `scale` times larger along each axis: coarse pixel `u'`
    /// covers full pixels `scale·u' … scale·u' + scale − 1` and its centre lies at
    /// `scale·u' + (scale − 1)/2` of the full image. A scale of 0 counts as 1.
    pub fn coarser(&self, scale: u32) -> Intrinsics {
        let s = scale.max(1) as f32;
        let offset = (s - 1.0) / 2.0;
        Intrinsics {
            fx: self.fx / s,
            fy: self.fy / s,
            cx: (self.cx - offset) / s,
            cy: (self.cy - offset) / s,
        }
    }

    /// The camera-space point at pixel `(u, v)` with depth `z_mm`.
    #[inline]
    pub fn backproject(&self, u: f32, v: f32, z_mm: f32) -> Point3<f32> {
        Point3::new(
            (u - self.cx) * z_mm / self.fx,
            (v - self.cy) * z_mm / self.fy,
            z_mm,
        )
    }
}

/// A borrowed depth frame: `width × height` raw sensor values, row-major; value × `depth_scale_mm`
/// is the depth (z) in millimetres; 0 means no measurement.
#[derive(Clone, Copy, Debug)]
pub struct DepthFrame<'a> {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The camera's intrinsics.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit (BOP's `depth_scale`).
    pub depth_scale_mm: f32,
    /// Raw depth values, `width × height`, row-major; 0 is no measurement.
    pub depth: &'a [u16],
}

impl<'a> DepthFrame<'a> {
    /// Checks the frame against its own header: size, intrinsics, depth scale.
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::InvalidFrame(format!(
                "depth frame size must be positive, got {}x{}",
                self.width, self.height
            )));
        }
        let expected = self.width as usize * self.height as usize;
        if self.depth.len() != expected {
            return Err(Error::InvalidFrame(format!(
                "depth frame {}x{} needs {} values, got {}",
                self.width,
                self.height,
                expected,
                self.depth.len()
            )));
        }
        self.intrinsics.validate_for(self.width, self.height)?;
        if !(self.depth_scale_mm.is_finite() && self.depth_scale_mm > 0.0) {
            return Err(Error::InvalidFrame(format!(
                "depth scale must be finite and positive, got {}",
                self.depth_scale_mm
            )));
        }
        Ok(())
    }

    /// Depth in millimetres at pixel `(u, v)`, or `None` where there is no measurement.
    #[inline]
    pub fn depth_mm(&self, u: u32, v: u32) -> Option<f32> {
        let raw = self.depth[(v * self.width + u) as usize];
        (raw != 0).then_some(raw as f32 * self.depth_scale_mm)
    }
}

/// An owned depth frame (what a renderer or a PNG reader produces).
#[derive(Clone, Debug)]
pub struct OwnedDepthFrame {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The camera's intrinsics.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit (BOP's `depth_scale`).
    pub depth_scale_mm: f32,
    /// Raw depth values, `width × height`, row-major; 0 is no measurement.
    pub depth: Vec<u16>,
}

impl OwnedDepthFrame {
    /// Borrows this frame.
    pub fn view(&self) -> DepthFrame<'_> {
        DepthFrame {
            width: self.width,
            height: self.height,
            intrinsics: self.intrinsics,
            depth_scale_mm: self.depth_scale_mm,
            depth: &self.depth,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Finite but impossible intrinsics are refused: a focal length in the wrong unit, or a
    /// principal point a frame's size away, would put poses 10³⁰ mm off or blame the depth.
    #[test]
    fn impossible_intrinsics_are_refused() {
        let with = |fx: f32, cx: f32| Intrinsics {
            fx,
            cx,
            ..Intrinsics::LMO
        };
        for (fx, cx) in [(1.0e30, 320.0), (f32::MIN_POSITIVE, 320.0), (0.5, 320.0)] {
            assert!(with(fx, cx).validate().is_err(), "fx {fx}");
        }
        for cx in [1.0e30, -641.0, 1281.0] {
            assert!(
                with(572.0, cx).validate().is_ok(),
                "no image to judge cx {cx} by"
            );
            assert!(with(572.0, cx).validate_for(640, 480).is_err(), "cx {cx}");
        }
        assert!(with(1.0, -640.0).validate_for(640, 480).is_ok());
        assert!(with(1.0e6, 1280.0).validate_for(640, 480).is_ok());
    }

    /// A point seen through the coarser camera lands in the coarse pixel whose block of full
    /// pixels holds the pixel it lands in at full resolution.
    #[test]
    fn coarser_pixels_cover_blocks_of_full_pixels() {
        let k = Intrinsics::LMO;
        for scale in [1u32, 2, 3, 4] {
            let c = k.coarser(scale);
            for i in 0..2000 {
                let p = Point3::new(
                    (i % 40) as f32 * 13.1 - 260.0,
                    (i / 40) as f32 * 9.7 - 240.0,
                    500.0 + (i % 7) as f32 * 90.0,
                );
                let (u, v) = k.pixel(&p);
                let (cu, cv) = c.pixel(&p);
                let s = scale as i64;
                // Within the block, or on its border where rounding may fall either way.
                let full = k.project(&p);
                let inside = |x: f32, q: i64| {
                    let lo = (q * s) as f32 - 0.5;
                    x >= lo - 1e-3 && x <= lo + s as f32 + 1e-3
                };
                assert!(
                    inside(full.x, cu) && inside(full.y, cv),
                    "scale {scale}: full ({u}, {v}) at {full:?}, coarse ({cu}, {cv})"
                );
            }
        }
        assert_eq!(k.coarser(0), k);
        assert_eq!(k.coarser(1), k);
    }

    #[test]
    fn pixel_rounds_like_the_library() {
        let k = Intrinsics {
            fx: 572.4,
            fy: 573.6,
            cx: 325.3,
            cy: 242.0,
        };
        let mut checked = 0;
        for i in -400..400 {
            for j in -300..300 {
                let p = Point3::new(i as f32 * 1.37, j as f32 * 0.91, 700.0 + (i + j) as f32);
                let uv = k.project(&p);
                assert_eq!(
                    k.pixel(&p),
                    (uv.x.round() as i64, uv.y.round() as i64),
                    "{p:?}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 800 * 600);
        // Halves go away from zero on both sides.
        let at = |x: f32| k.pixel(&Point3::new((x - k.cx) / k.fx, 0.0, 1.0)).0;
        assert_eq!(at(2.5), 3);
        assert_eq!(at(-2.5), -3);
    }
}
