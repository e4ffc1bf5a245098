//! What a caller needs of a detection's answer, beyond which objects: a minimum score, how far
//! apart two instances lie, where reference points may be taken (a pixel rectangle), which
//! poses a gripper can take (the tilt of a model axis from a camera direction) and the order of
//! the answer. [`Requirements::default`] asks for nothing: every pose, best score first.

use nalgebra::{Point3, Unit, Vector3};

use crate::geometry::camera::Intrinsics;
use crate::{Error, Pose, Result};

/// A pixel rectangle of the depth frame: columns `x .. x + width`, rows `y .. y + height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRegion {
    /// First column, pixels.
    pub x: u32,
    /// First row, pixels.
    pub y: u32,
    /// Columns, pixels.
    pub width: u32,
    /// Rows, pixels.
    pub height: u32,
}

impl PixelRegion {
    /// Refuses an empty rectangle or one that reaches outside a `width × height` frame.
    pub fn check(&self, width: u32, height: u32) -> Result<()> {
        let right = self.x as u64 + self.width as u64;
        let bottom = self.y as u64 + self.height as u64;
        if self.width == 0 || self.height == 0 {
            return Err(Error::InvalidParameter(format!(
                "region of interest {}x{} is empty: width and height must be at least 1 pixel",
                self.width, self.height
            )));
        }
        if right > width as u64 || bottom > height as u64 {
            return Err(Error::InvalidParameter(format!(
                "region of interest x {}..{}, y {}..{} reaches outside the {width}x{height} frame",
                self.x, right, self.y, bottom
            )));
        }
        Ok(())
    }

    /// Whether the camera-space point `p` projects into the rectangle.
    pub fn holds(&self, intrinsics: &Intrinsics, p: &Point3<f32>) -> bool {
        if p.z <= 0.0 {
            return false;
        }
        let (u, v) = intrinsics.pixel(p);
        u >= self.x as i64
            && v >= self.y as i64
            && u < self.x as i64 + self.width as i64
            && v < self.y as i64 + self.height as i64
    }
}

/// Bin picking's pose restriction: the model axis a gripper approaches along may lean at most
/// `max_angle` away from a direction in the camera's frame (for a camera above the bin, `-z`:
/// towards the camera).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseRestriction {
    /// In model coordinates.
    pub model_axis: Unit<Vector3<f32>>,
    /// In camera coordinates.
    pub camera_direction: Unit<Vector3<f32>>,
    /// Radians, 0 to π.
    pub max_angle: f32,
}

impl PoseRestriction {
    /// A restriction from raw vectors (normalised here) and an angle in degrees, refusing zero
    /// or non-finite vectors and angles outside 0 to 180°.
    pub fn new(
        model_axis: [f32; 3],
        camera_direction: [f32; 3],
        max_angle_deg: f32,
    ) -> Result<Self> {
        let unit = |what: &str, v: [f32; 3]| {
            let v = Vector3::from(v);
            if !v.iter().all(|c| c.is_finite()) || v.norm() < 1e-6 {
                return Err(Error::InvalidParameter(format!(
                    "pose restriction: the {what} must be a finite, non-zero vector, got {:?}",
                    [v.x, v.y, v.z]
                )));
            }
            Ok(Unit::new_normalize(v))
        };
        if !(0.0..=180.0).contains(&max_angle_deg) {
            return Err(Error::InvalidParameter(format!(
                "pose restriction: the maximum angle must be 0 to 180 degrees, got {max_angle_deg}"
            )));
        }
        Ok(PoseRestriction {
            model_axis: unit("model axis", model_axis)?,
            camera_direction: unit("camera direction", camera_direction)?,
            max_angle: max_angle_deg.to_radians(),
        })
    }

    /// The angle between the posed model axis and the camera direction, radians.
    pub fn angle(&self, pose: &Pose) -> f32 {
        let axis = pose.rotation * self.model_axis.into_inner();
        axis.dot(&self.camera_direction).clamp(-1.0, 1.0).acos()
    }

    /// Whether a gripper can take the object at `pose`.
    pub fn allows(&self, pose: &Pose) -> bool {
        self.angle(pose) <= self.max_angle
    }
}

/// The order of an object's hypotheses in the answer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Order {
    /// Best score first.
    #[default]
    Score,
    /// Nearest to the camera first (the distance of the model's centre from the camera's
    /// origin): in a bin, the parts on top.
    Distance,
}

/// What the caller needs of the answer.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Requirements {
    /// Hypotheses scoring below this (0 to 1) are left out, even to fill the list.
    pub min_score: f32,
    /// Overrides [`crate::detect::detector::DetectParams::nms_distance_fraction`]: two
    /// hypotheses whose centres lie closer than this fraction of the diameter are one instance.
    pub instance_distance_fraction: Option<f32>,
    /// Reference points only from scene points that project into this rectangle; partners
    /// still come from the whole frame, so an object the rectangle cuts keeps its votes.
    pub region: Option<PixelRegion>,
    /// Only poses this allows.
    pub pose_restriction: Option<PoseRestriction>,
    /// The order of each object's hypotheses.
    pub order: Order,
}

/// Largest [`Requirements::instance_distance_fraction`]: two instances' centres lying two
/// diameters apart are apart whatever their shapes.
pub const MAX_INSTANCE_DISTANCE_FRACTION: f32 = 2.0;

impl Requirements {
    /// Refuses values out of range, and a region outside the `width × height` frame.
    pub fn check(&self, width: u32, height: u32) -> Result<()> {
        if !(0.0..=1.0).contains(&self.min_score) {
            return Err(Error::InvalidParameter(format!(
                "minimum score must be 0 to 1, got {}",
                self.min_score
            )));
        }
        if let Some(f) = self.instance_distance_fraction {
            if !(f > 0.0 && f <= MAX_INSTANCE_DISTANCE_FRACTION) {
                return Err(Error::InvalidParameter(format!(
                    "instance distance must be above 0 and at most \
                     {MAX_INSTANCE_DISTANCE_FRACTION} diameters, got {f}"
                )));
            }
        }
        if let Some(r) = &self.region {
            r.check(width, height)?;
        }
        if let Some(p) = &self.pose_restriction {
            if !(0.0..=std::f32::consts::PI).contains(&p.max_angle) {
                return Err(Error::InvalidParameter(format!(
                    "pose restriction: the maximum angle must be 0 to 180 degrees, got {}",
                    p.max_angle.to_degrees()
                )));
            }
        }
        Ok(())
    }

    /// Whether a model whose surface points are `points` (model coordinates), at `pose`,
    /// reaches into the region of interest with any of them (any pose without a region): what a
    /// voted pose has from its reference point, which lies in the region, and a hint must show
    /// after ICP.
    pub fn region_reached(
        &self,
        intrinsics: &Intrinsics,
        points: &[Point3<f32>],
        pose: &Pose,
    ) -> bool {
        self.region
            .as_ref()
            .is_none_or(|r| points.iter().any(|p| r.holds(intrinsics, &(pose * p))))
    }

    /// Whether a pose passes the pose restriction (any pose without one).
    pub fn allows(&self, pose: &Pose) -> bool {
        self.pose_restriction
            .as_ref()
            .is_none_or(|r| r.allows(pose))
    }

    /// What of these requirements leaves out a refined pose scoring `score`, if anything:
    /// the minimum score, the pose restriction (judged on `reported`, the pose as the answer
    /// gives it, canonical under the object's symmetry) or the region (reached by the surface
    /// `points` at `pose`). The detector and its diagnosis ask this one question.
    pub fn refusal(
        &self,
        score: f32,
        pose: &Pose,
        reported: &Pose,
        intrinsics: &Intrinsics,
        points: &[Point3<f32>],
    ) -> Option<&'static str> {
        if score < self.min_score {
            Some("below the request's minimum score")
        } else if !self.allows(reported) {
            Some("refined outside the request's pose restriction")
        } else if !self.region_reached(intrinsics, points, pose) {
            Some("refined outside the request's region of interest")
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn a_region_must_lie_in_the_frame_and_holds_what_projects_into_it() {
        let r = PixelRegion {
            x: 100,
            y: 50,
            width: 200,
            height: 100,
        };
        assert!(r.check(640, 480).is_ok());
        let e = r.check(250, 480).unwrap_err().to_string();
        assert!(e.contains("250x480") && e.contains("100..300"), "{e}");
        let empty = PixelRegion { width: 0, ..r };
        assert!(empty
            .check(640, 480)
            .unwrap_err()
            .to_string()
            .contains("empty"));
        let k = Intrinsics::LMO;
        let at = |u: f32, v: f32| k.backproject(u, v, 800.0);
        assert!(r.holds(&k, &at(100.0, 50.0)));
        assert!(r.holds(&k, &at(299.0, 149.0)));
        assert!(!r.holds(&k, &at(300.0, 100.0)));
        assert!(!r.holds(&k, &at(150.0, 49.0)));
        assert!(!r.holds(&k, &Point3::new(0.0, 0.0, -5.0)));
    }

    #[test]
    fn a_pose_restriction_measures_the_tilt_of_the_posed_axis() {
        let up = PoseRestriction::new([0.0, 0.0, 1.0], [0.0, 0.0, -2.0], 30.0).unwrap();
        let facing_camera = Pose::from_parts(
            Translation3::new(0.0, 0.0, 800.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI),
        );
        assert!(up.angle(&facing_camera) < 1e-4);
        assert!(up.allows(&facing_camera));
        let tilt = |deg: f32| facing_camera * Pose::rotation(Vector3::y() * deg.to_radians());
        assert!((up.angle(&tilt(25.0)).to_degrees() - 25.0).abs() < 1e-3);
        assert!(up.allows(&tilt(29.0)) && !up.allows(&tilt(31.0)));
        assert!(
            !up.allows(&Pose::identity()),
            "the axis points away from the camera"
        );

        for (axis, direction, angle) in [
            ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 10.0),
            ([0.0, 0.0, 1.0], [f32::NAN, 0.0, 1.0], 10.0),
            ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 181.0),
            ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], -1.0),
        ] {
            let e = PoseRestriction::new(axis, direction, angle).unwrap_err();
            assert!(e.to_string().contains("pose restriction"), "{e}");
        }
    }

    #[test]
    fn requirements_out_of_range_are_refused_naming_the_range() {
        let ok = Requirements::default();
        assert!(ok.check(640, 480).is_ok());
        let e = Requirements {
            min_score: 1.5,
            ..ok
        }
        .check(640, 480)
        .unwrap_err();
        assert!(e.to_string().contains("0 to 1"), "{e}");
        for bad in [0.0, -0.1, 2.5, f32::NAN] {
            let e = Requirements {
                instance_distance_fraction: Some(bad),
                ..ok
            }
            .check(640, 480)
            .unwrap_err();
            assert!(e.to_string().contains("at most 2"), "{e}");
        }
    }
}
