//! An object's symmetries (METHOD.md §1.8): the rigid transforms of model coordinates that map
//! the object onto itself, so that poses differing by one of them are the same physical pose.
//!
//! [`Symmetry`] holds a list of discrete transforms (the identity not listed) and at most one
//! continuous axis, as BOP's `models_info.json` gives them (`symmetries_discrete`,
//! `symmetries_continuous`), or as [`Symmetry::generated`] makes them from
//! [`SymmetryElement`]s (`ppf model build --symmetry z:2`). A pose `P` then stands for every pose
//! `P · S · C(θ)`: `S` the identity or one of the discrete transforms, `C(θ)` any turn about the
//! axis. Detection reports the one [`Symmetry::canonical`] picks, and clustering and instance
//! suppression compare poses through [`Symmetry::closest_equivalent`] and
//! [`Symmetry::fixed_point`].

use std::str::FromStr;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::model::subsample::OrientedPoints;
use crate::{Error, Pose, Result};

/// At most this many discrete transforms (the identity not counted): each costs a comparison per
/// hypothesis and cluster. A 24-tooth gear turned over has 47.
pub const MAX_DISCRETE: usize = 99;

/// A symmetry holds for a model when nine in ten of its surface points, so transformed, lie
/// within this fraction of the diameter of a surface point facing the same way (within 30°). The
/// surface points' own spacing (0.025 D) and a real part's departures from its symmetry set the
/// floor: the LM-O egg box and glue measure 0.024 D and 0.019 D under the half turns of their
/// `models_info.json`, and 0.13 D and 0.11 D under a quarter turn about the same axis; the egg
/// box, nearly a box, 0.071 D under a half turn about x, which BOP does not list. A median
/// would not do: half a U-channel's surface (its side walls) maps onto itself when it is turned
/// upside down.
pub const MAX_MISFIT_FRACTION: f32 = 0.04;

/// A continuous rotational symmetry: any turn about the line through `point_mm` along
/// `direction` maps the object onto itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SymmetryAxis {
    /// Direction of the axis, model coordinates.
    pub direction: Unit<Vector3<f32>>,
    /// A point on the axis, model coordinates, mm.
    pub point_mm: Point3<f32>,
}

impl SymmetryAxis {
    /// The turn by `angle` (radians) about the axis.
    pub fn turn(&self, angle: f32) -> Pose {
        let rotation = UnitQuaternion::from_axis_angle(&self.direction, angle);
        let t = self.point_mm.coords - rotation * self.point_mm.coords;
        Pose::from_parts(Translation3::from(t), rotation)
    }

    /// The point of the axis nearest `p`.
    fn project(&self, p: &Point3<f32>) -> Point3<f32> {
        let a = self.direction.into_inner();
        self.point_mm + a * (p - self.point_mm).dot(&a)
    }
}

/// The symmetries of an object (see the module documentation). The default has none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Symmetry {
    /// Transforms other than the identity that map the object onto itself (model to model, mm).
    pub discrete: Vec<Pose>,
    /// An axis about which any turn maps the object onto itself.
    pub continuous: Option<SymmetryAxis>,
}

/// The angle (radians) of a turn about `axis` that, applied last, brings `q` closest to the
/// identity: `q · R(axis, θ)` has scalar part `w cos θ/2 − (v·a) sin θ/2`, largest at
/// `θ = −2 atan2(v·a, w)`.
fn turn_towards_identity(q: &UnitQuaternion<f32>, axis: &Unit<Vector3<f32>>) -> f32 {
    -2.0 * q.imag().dot(axis).atan2(q.w)
}

impl Symmetry {
    /// Whether the object has no symmetry at all.
    pub fn is_none(&self) -> bool {
        self.discrete.is_empty() && self.continuous.is_none()
    }

    /// The same symmetry of the object scaled by `factor` (a mesh given in other units): the
    /// translations and the axis point scale, the rotations stay.
    pub fn scaled(&self, factor: f32) -> Symmetry {
        Symmetry {
            discrete: self
                .discrete
                .iter()
                .map(|s| {
                    Pose::from_parts(
                        Translation3::from(s.translation.vector * factor),
                        s.rotation,
                    )
                })
                .collect(),
            continuous: self.continuous.map(|a| SymmetryAxis {
                point_mm: Point3::from(a.point_mm.coords * factor),
                ..a
            }),
        }
    }

    /// The identity and the discrete transforms, in that order.
    pub fn discrete_with_identity(&self) -> impl Iterator<Item = Pose> + '_ {
        std::iter::once(Pose::identity()).chain(self.discrete.iter().copied())
    }

    /// How many distinct poses one pose stands for: `None` for infinitely many.
    pub fn order(&self) -> Option<usize> {
        self.continuous.is_none().then_some(self.discrete.len() + 1)
    }

    /// Among the poses equivalent to `pose`, the one whose rotation is closest to `to` (the
    /// smallest angle between them); an exact tie goes to the identity, then to the earlier
    /// discrete transform. With a continuous axis, each discrete candidate `pose · S` is turned
    /// about the axis by the angle that brings it closest.
    pub fn closest_equivalent(&self, pose: &Pose, to: &UnitQuaternion<f32>) -> Pose {
        if self.is_none() {
            return *pose;
        }
        let to_inverse = to.inverse();
        let mut best = (f32::NEG_INFINITY, *pose);
        for s in self.discrete_with_identity() {
            let mut candidate = pose * s;
            if let Some(axis) = &self.continuous {
                let relative = to_inverse * candidate.rotation;
                candidate *= axis.turn(turn_towards_identity(&relative, &axis.direction));
            }
            // |w| of the relative rotation is cos(angle / 2): larger is closer.
            let closeness = (to_inverse * candidate.rotation).w.abs();
            if closeness > best.0 {
                best = (closeness, candidate);
            }
        }
        best.1
    }

    /// Translation (mm) and rotation (degrees) errors of `pose` against `target`, through the
    /// symmetry: the equivalent of `pose` closest to the target is compared. One pose of a
    /// symmetric object turned by a symmetry is as right as the other.
    pub fn pose_errors(&self, pose: &Pose, target: &Pose) -> (f32, f32) {
        let pose = self.closest_equivalent(pose, &target.rotation);
        (
            (pose.translation.vector - target.translation.vector).norm(),
            pose.rotation.angle_to(&target.rotation).to_degrees(),
        )
    }

    /// The canonical pose among those equivalent to `pose`: the one whose rotation is closest to
    /// the identity (METHOD.md §1.8). Every pose equivalent to `pose` gives the same one, up to
    /// rounding, except at exact ties.
    pub fn canonical(&self, pose: &Pose) -> Pose {
        self.closest_equivalent(pose, &UnitQuaternion::identity())
    }

    /// A point of the model that every symmetry leaves in place, near `near`: `near` averaged
    /// over the discrete transforms (and the identity), then put on the axis. Equivalent poses
    /// put it at the same place in the camera frame. Without symmetry, `near` itself.
    pub fn fixed_point(&self, near: &Point3<f32>) -> Point3<f32> {
        let sum = self
            .discrete_with_identity()
            .fold(Vector3::zeros(), |acc, s| acc + (s * near).coords);
        let mean = Point3::from(sum / (self.discrete.len() + 1) as f32);
        match &self.continuous {
            Some(axis) => axis.project(&mean),
            None => mean,
        }
    }

    /// The symmetry generated by `elements`: the group of their products, an N-fold turn
    /// contributing its N − 1 non-trivial powers. Transforms that differ by a turn about the
    /// continuous axis count once; two continuous axes (a sphere) are refused.
    pub fn generated(elements: &[SymmetryElement]) -> Result<Symmetry> {
        let bad = |what: String| Err(Error::InvalidParameter(what));
        let mut continuous: Option<SymmetryAxis> = None;
        let mut generators = Vec::new();
        for e in elements {
            match *e {
                SymmetryElement::Turns { axis, order } => {
                    generators.push(axis.turn(std::f32::consts::TAU / order as f32));
                }
                SymmetryElement::Continuous(axis) => match &continuous {
                    Some(known) if !same_line(known, &axis) => {
                        return bad(
                            "two different continuous symmetry axes (only a sphere has them): \
                             give one"
                                .into(),
                        )
                    }
                    _ => continuous = Some(axis),
                },
            }
        }
        let mut group = Symmetry {
            discrete: Vec::new(),
            continuous,
        };
        // Closure under products, breadth first from the generators.
        let mut frontier = vec![Pose::identity()];
        while let Some(element) = frontier.pop() {
            for g in &generators {
                let product = g * element;
                if group.contains(&product) {
                    continue;
                }
                if group.discrete.len() == MAX_DISCRETE {
                    return bad(format!(
                        "the symmetries given make more than {} distinct poses of one; at most \
                         {} are supported",
                        MAX_DISCRETE + 1,
                        MAX_DISCRETE + 1
                    ));
                }
                group.discrete.push(product);
                frontier.push(product);
            }
        }
        Ok(group)
    }

    /// Whether `transform` is the identity or one of the discrete transforms, up to a turn about
    /// the continuous axis (to 0.01° and 0.001 mm).
    fn contains(&self, transform: &Pose) -> bool {
        self.discrete_with_identity().any(|s| {
            let mut relative = s.inverse() * transform;
            if let Some(axis) = &self.continuous {
                relative *= axis.turn(turn_towards_identity(&relative.rotation, &axis.direction));
            }
            relative.rotation.angle() < 1e-4 && relative.translation.vector.norm() < 1e-3
        })
    }

    /// Refuses what no object of diameter `diameter_mm` can have: non-finite numbers, more than
    /// [`MAX_DISCRETE`] transforms, a transform that moves the model by more than its diameter,
    /// an axis point farther than that from the origin, and a discrete transform that does not
    /// map the continuous axis onto itself (within 5° and 0.05 D).
    pub fn validate(&self, diameter_mm: f32) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidParameter(format!("symmetry: {what}")));
        if self.discrete.len() > MAX_DISCRETE {
            return bad(format!(
                "{} discrete transforms, at most {MAX_DISCRETE}",
                self.discrete.len()
            ));
        }
        for (i, s) in self.discrete.iter().enumerate() {
            let t = s.translation.vector;
            if !(t.iter().all(|v| v.is_finite()) && s.rotation.coords.iter().all(|v| v.is_finite()))
            {
                return bad(format!("discrete transform {i} is not finite"));
            }
            if t.norm() > diameter_mm {
                return bad(format!(
                    "discrete transform {i} moves the model by {:.1} mm, more than its diameter \
                     ({diameter_mm:.1} mm): not a symmetry of it",
                    t.norm()
                ));
            }
        }
        if let Some(axis) = &self.continuous {
            let finite = axis.direction.iter().chain(axis.point_mm.iter());
            if !finite.copied().all(f32::is_finite) {
                return bad("the continuous axis is not finite".into());
            }
            if axis.point_mm.coords.norm() > diameter_mm {
                return bad(format!(
                    "the continuous axis passes {:.1} mm from the model's origin, more than its \
                     diameter ({diameter_mm:.1} mm)",
                    axis.point_mm.coords.norm()
                ));
            }
            for (i, s) in self.discrete.iter().enumerate() {
                let turned = s.rotation * axis.direction;
                let angle = turned.dot(&axis.direction).abs().min(1.0).acos();
                let moved = s * axis.point_mm;
                let off = (moved - axis.project(&moved)).norm();
                if angle > 5f32.to_radians() || off > 0.05 * diameter_mm {
                    return bad(format!(
                        "discrete transform {i} moves the continuous axis ({:.1}° and {off:.1} \
                         mm): the two cannot both be symmetries of one object",
                        angle.to_degrees()
                    ));
                }
            }
        }
        Ok(())
    }

    /// How far `surface` (a model's oriented points, mm) lies from itself under each symmetry:
    /// for each discrete transform, and for turns about the axis by 45° to 315° in steps of 45°,
    /// the distance (mm) within which nine in ten of the transformed points have an
    /// untransformed one facing the same way (within 30°; if none of a point's 8 nearest does,
    /// the farthest of them counts). Each is `(what, distance_mm)`, `what` naming the transform
    /// for a person.
    pub fn misfits(&self, surface: &OrientedPoints) -> Vec<(String, f32)> {
        if surface.is_empty() {
            return Vec::new();
        }
        let coords: Vec<[f32; 3]> = surface.positions.iter().map(|p| [p.x, p.y, p.z]).collect();
        let Ok(tree) = ImmutableKdTree::<f32, 3>::new_from_slice(&coords) else {
            return Vec::new();
        };
        let k = std::num::NonZeroUsize::new(8).expect("not zero");
        let min_cos = 30f32.to_radians().cos();
        let misfit = |transform: &Pose| {
            let mut d: Vec<f32> = surface
                .positions
                .iter()
                .zip(&surface.normals)
                .map(|(p, n)| {
                    let (q, m) = (transform * p, transform.rotation * n);
                    let near = tree
                        .query(&[q.x, q.y, q.z])
                        .nearest_n::<SquaredEuclidean<f32>>(k)
                        .execute();
                    // The nearest point facing the same way; past the 8 nearest, the farthest.
                    near.iter()
                        .find(|nb| surface.normals[nb.item as usize].dot(&m) >= min_cos)
                        .or(near.last())
                        .map_or(f32::INFINITY, |nb| nb.distance.sqrt())
                })
                .collect();
            let at = (d.len() - 1) * 9 / 10;
            *d.select_nth_unstable_by(at, f32::total_cmp).1
        };
        let mut out = Vec::new();
        for (i, s) in self.discrete.iter().enumerate() {
            out.push((
                format!("discrete transform {} ({})", i + 1, describe_turn(s)),
                misfit(s),
            ));
        }
        if let Some(axis) = &self.continuous {
            for step in 1..8 {
                let degrees = 45 * step;
                out.push((
                    format!("a turn of {degrees}° about the continuous axis"),
                    misfit(&axis.turn((degrees as f32).to_radians())),
                ));
            }
        }
        out
    }

    /// Refuses a symmetry that the object's `surface` points (mm) do not have: one of
    /// [`Symmetry::misfits`] above [`MAX_MISFIT_FRACTION`] of `diameter_mm`.
    pub fn check_holds(&self, surface: &OrientedPoints, diameter_mm: f32) -> Result<()> {
        let limit = MAX_MISFIT_FRACTION * diameter_mm;
        for (what, off) in self.misfits(surface) {
            if off > limit {
                return Err(Error::InvalidParameter(format!(
                    "symmetry: the object does not have it: {what} moves a tenth of its surface \
                     {off:.1} mm or more off itself (at most {limit:.1} mm, {MAX_MISFIT_FRACTION} \
                     of the diameter, is allowed)"
                )));
            }
        }
        Ok(())
    }

    /// The discrete transforms as stored in a model file: `[w, x, y, z, tx, ty, tz]`, the
    /// rotation as a unit quaternion, then the translation (mm).
    pub fn stored_discrete(&self) -> Vec<[f32; 7]> {
        self.discrete
            .iter()
            .map(|s| {
                let (q, t) = (s.rotation, s.translation.vector);
                [q.w, q.i, q.j, q.k, t.x, t.y, t.z]
            })
            .collect()
    }

    /// The continuous axis as stored in a model file: `[dx, dy, dz, px, py, pz]`, the unit
    /// direction, then a point on the axis (mm). At most one.
    pub fn stored_continuous(&self) -> Vec<[f32; 6]> {
        self.continuous
            .iter()
            .map(|a| {
                let (d, p) = (a.direction, a.point_mm);
                [d.x, d.y, d.z, p.x, p.y, p.z]
            })
            .collect()
    }

    /// The symmetry stored as [`Symmetry::stored_discrete`] and
    /// [`Symmetry::stored_continuous`] give it, bit for bit; refuses quaternions and directions
    /// that are not unit length (to 10⁻⁵: they were stored so) and more than one axis.
    pub fn from_stored(discrete: &[[f32; 7]], continuous: &[[f32; 6]]) -> Result<Symmetry> {
        let bad = |what: String| Err(Error::InvalidParameter(format!("symmetry: {what}")));
        let mut out = Symmetry::default();
        for (i, s) in discrete.iter().enumerate() {
            let q = nalgebra::Quaternion::new(s[0], s[1], s[2], s[3]);
            if !unit_length(q.norm()) {
                return bad(format!(
                    "discrete transform {i}: its quaternion has norm {}, not 1",
                    q.norm()
                ));
            }
            out.discrete.push(Pose::from_parts(
                Translation3::new(s[4], s[5], s[6]),
                UnitQuaternion::new_unchecked(q),
            ));
        }
        match continuous {
            [] => {}
            [a] => {
                let d = Vector3::new(a[0], a[1], a[2]);
                if !unit_length(d.norm()) {
                    return bad(format!("the axis direction has length {}, not 1", d.norm()));
                }
                out.continuous = Some(SymmetryAxis {
                    direction: Unit::new_unchecked(d),
                    point_mm: Point3::new(a[3], a[4], a[5]),
                });
            }
            more => return bad(format!("{} continuous axes, at most one", more.len())),
        }
        Ok(out)
    }

    /// One line for a person: "none", "discrete, 2 poses alike", "continuous about the axis
    /// (0.000, 0.000, 1.000) through (0.0, 0.0, 0.0) mm, and discrete, 2 poses alike per turn".
    pub fn describe(&self) -> String {
        let alike = self.discrete.len() + 1;
        match &self.continuous {
            None if self.discrete.is_empty() => "none".into(),
            None => format!("discrete, {alike} poses alike"),
            Some(a) => {
                let (d, p) = (a.direction, a.point_mm);
                let axis = format!(
                    "continuous about the axis ({:.3}, {:.3}, {:.3}) through ({:.1}, {:.1}, {:.1}) mm",
                    d.x, d.y, d.z, p.x, p.y, p.z
                );
                if self.discrete.is_empty() {
                    axis
                } else {
                    format!("{axis}, and discrete, {alike} poses alike per turn")
                }
            }
        }
    }
}

/// "a turn of 180° about (0.00, 0.00, 1.00)": the rotation of `transform`, for a person. A half
/// turn's axis, whose sign is arbitrary, is shown with its largest component positive.
fn describe_turn(transform: &Pose) -> String {
    let Some((axis, angle)) = transform.rotation.axis_angle() else {
        return "no turn".into();
    };
    let mut axis = axis.into_inner();
    let largest = axis
        .iter()
        .copied()
        .fold(0f32, |m, v| if v.abs() > m.abs() { v } else { m });
    if angle > std::f32::consts::PI - 1e-3 && largest < 0.0 {
        axis = -axis;
    }
    // Adding 0 turns -0 into 0, and rounding first shows a tiny negative component as 0.00.
    let shown = |v: f32| (v * 100.0).round() / 100.0 + 0.0;
    format!(
        "a turn of {:.0}° about ({:.2}, {:.2}, {:.2})",
        angle.to_degrees(),
        shown(axis.x),
        shown(axis.y),
        shown(axis.z)
    )
}

/// Whether a stored quaternion's or direction's norm is 1 (to 10⁻⁵); false for NaN.
fn unit_length(norm: f32) -> bool {
    (norm - 1.0).abs() < 1e-5
}

/// Whether two axes are the same line (to about 0.3° and 0.001 mm).
fn same_line(a: &SymmetryAxis, b: &SymmetryAxis) -> bool {
    a.direction.dot(&b.direction).abs() > 1.0 - 1e-5
        && (a.project(&b.point_mm) - b.point_mm).norm() < 1e-3
}

/// One generator of a symmetry, as `ppf model build --symmetry` takes it:
///
/// - `AXIS:N`: every turn by a multiple of 360°/N about the axis (N from 2 to 100);
/// - `AXIS:inf`: any turn about the axis;
///
/// each optionally followed by `@X,Y,Z`, a point of the axis in mm (else the model's origin).
/// `AXIS` is `x`, `y`, `z` or a direction `A,B,C`. Examples: `z:2`, `z:inf`, `0,1,1:4@0,0,12.5`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SymmetryElement {
    /// The turns by multiples of 360°/`order` about `axis`.
    Turns {
        /// The axis turned about.
        axis: SymmetryAxis,
        /// How many of the turns make a full turn; parsing takes 2 to 100.
        order: u32,
    },
    /// Any turn about the axis.
    Continuous(SymmetryAxis),
}

/// What [`SymmetryElement`]'s text looks like, for refusals.
const ELEMENT_FORM: &str = "AXIS:N or AXIS:inf, optionally @X,Y,Z (a point of the axis, mm), \
     AXIS being x, y, z or A,B,C; e.g. z:2, z:inf, 0,1,1:4@0,0,12.5";

fn three_numbers(text: &str, what: &str) -> std::result::Result<Vector3<f32>, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let numbers: Vec<f32> = parts
        .iter()
        .filter_map(|p| p.parse::<f32>().ok().filter(|v| v.is_finite()))
        .collect();
    if parts.len() != 3 || numbers.len() != 3 {
        return Err(format!(
            "{what} {text:?} is not three finite numbers separated by commas"
        ));
    }
    Ok(Vector3::new(numbers[0], numbers[1], numbers[2]))
}

impl FromStr for SymmetryElement {
    type Err = String;

    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let refuse = |why: String| Err(format!("{text:?}: {why} (expected {ELEMENT_FORM})"));
        let text = text.trim();
        let (turns, point) = match text.split_once('@') {
            Some((turns, point)) => (turns, Some(point)),
            None => (text, None),
        };
        let Some((axis, order)) = turns.rsplit_once(':') else {
            return refuse("no ':' between the axis and the order".into());
        };
        let direction = match axis.trim() {
            "x" | "X" => Vector3::x(),
            "y" | "Y" => Vector3::y(),
            "z" | "Z" => Vector3::z(),
            other => match three_numbers(other, "the axis") {
                Ok(v) => v,
                Err(e) => return refuse(e),
            },
        };
        let Some(direction) = Unit::try_new(direction, 1e-6) else {
            return refuse("the axis has zero length".into());
        };
        let point_mm = match point {
            Some(p) => match three_numbers(p, "the point") {
                Ok(v) => Point3::from(v),
                Err(e) => return refuse(e),
            },
            None => Point3::origin(),
        };
        let axis = SymmetryAxis {
            direction,
            point_mm,
        };
        let order = order.trim();
        if order.eq_ignore_ascii_case("inf") {
            return Ok(SymmetryElement::Continuous(axis));
        }
        match order.parse::<u32>() {
            Ok(n) if (2..=100).contains(&n) => Ok(SymmetryElement::Turns { axis, order: n }),
            Ok(n) => refuse(format!(
                "the order {n} is not 2 to 100 (2 is a half turn; inf is any turn)"
            )),
            Err(_) => refuse(format!("the order {order:?} is not a whole number or inf")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::{FRAC_PI_2, PI};

    fn pose(t: [f32; 3], axis: Vector3<f32>, angle: f32) -> Pose {
        Pose::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), angle),
        )
    }

    fn element(text: &str) -> SymmetryElement {
        text.parse().unwrap()
    }

    fn close(a: &Pose, b: &Pose) -> bool {
        a.rotation.angle_to(&b.rotation) < 1e-4
            && (a.translation.vector - b.translation.vector).norm() < 1e-3
    }

    #[test]
    fn elements_are_read_from_their_text() {
        assert_eq!(
            element("z:2"),
            SymmetryElement::Turns {
                axis: SymmetryAxis {
                    direction: Vector3::z_axis(),
                    point_mm: Point3::origin()
                },
                order: 2
            }
        );
        match element(" 0,3,4 :INF@1, 2,3 ") {
            SymmetryElement::Continuous(a) => {
                assert!((a.direction.into_inner() - Vector3::new(0.0, 0.6, 0.8)).norm() < 1e-6);
                assert_eq!(a.point_mm, Point3::new(1.0, 2.0, 3.0));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn malformed_elements_are_refused_saying_why() {
        for (text, why) in [
            ("z2", "no ':'"),
            ("w:2", "the axis \"w\" is not three finite numbers"),
            ("0,0:2", "the axis \"0,0\" is not three"),
            ("0,0,0:2", "zero length"),
            ("z:1", "the order 1 is not 2 to 100"),
            ("z:101", "the order 101"),
            ("z:half", "the order \"half\" is not a whole number or inf"),
            ("z:-2", "the order \"-2\""),
            ("z:2@1,2", "the point \"1,2\" is not three"),
            ("z:2@1,2,nan", "the point"),
            ("", "no ':'"),
        ] {
            let e = text.parse::<SymmetryElement>().unwrap_err();
            assert!(
                e.contains(why) && e.contains("expected AXIS:N"),
                "{text}: {e}"
            );
        }
    }

    #[test]
    fn a_generated_group_is_closed_and_counts_each_transform_once() {
        let four = Symmetry::generated(&[element("z:4")]).unwrap();
        assert_eq!(four.order(), Some(4));
        let dihedral = Symmetry::generated(&[element("z:4"), element("x:2")]).unwrap();
        assert_eq!(dihedral.order(), Some(8));
        // Two generators of one group give it once.
        let same = Symmetry::generated(&[element("z:4"), element("z:2")]).unwrap();
        assert_eq!(same.order(), Some(4));
        // Discrete turns about the continuous axis add nothing; a flip across it does, once.
        let cylinder = Symmetry::generated(&[
            element("z:inf"),
            element("z:6"),
            element("x:2"),
            element("y:2"),
        ])
        .unwrap();
        assert_eq!(cylinder.discrete.len(), 1);
        assert!(cylinder.continuous.is_some());
        // Products stay about the given point: a half turn about z through (10, 0, 0).
        let off = Symmetry::generated(&[element("z:2@10,0,0")]).unwrap();
        let p = Point3::new(10.0, 0.0, 5.0);
        assert!((off.discrete[0] * p - p).norm() < 1e-4);
        assert!(Symmetry::generated(&[element("z:inf"), element("x:inf")])
            .unwrap_err()
            .to_string()
            .contains("two different continuous symmetry axes"));
        let huge = Symmetry::generated(&[element("z:100"), element("x:2")]).unwrap_err();
        assert!(huge.to_string().contains("at most 100"), "{huge}");
        assert!(Symmetry::generated(&[]).unwrap().is_none());
    }

    /// Every pose equivalent to one gives the same canonical pose, the one nearest the identity.
    #[test]
    fn equivalent_poses_have_one_canonical_pose() {
        let half = Symmetry::generated(&[element("z:2@3,4,0")]).unwrap();
        let p = pose([10.0, -20.0, 700.0], Vector3::new(0.2, 1.0, 0.3), 2.5);
        let q = p * half.discrete[0];
        let (cp, cq) = (half.canonical(&p), half.canonical(&q));
        assert!(close(&cp, &cq), "{cp:?} {cq:?}");
        // It is one of the two, the one with the smaller rotation angle.
        let smaller = if p.rotation.angle() <= q.rotation.angle() {
            p
        } else {
            q
        };
        assert!(close(&cp, &smaller));

        let shaft = Symmetry::generated(&[element("0,0,1:inf@5,0,0")]).unwrap();
        let p = pose([10.0, -20.0, 700.0], Vector3::new(1.0, 1.0, 0.3), 2.0);
        let canonical = shaft.canonical(&p);
        for k in 0..12 {
            let turned = p * shaft.continuous.unwrap().turn(k as f32 * 0.5);
            assert!(close(&shaft.canonical(&turned), &canonical), "{k}");
            assert!(canonical.rotation.angle() <= turned.rotation.angle() + 1e-5);
        }
        // The model's axis is where it was: the turn changes nothing on the object.
        let on_axis = Point3::new(5.0, 0.0, 30.0);
        assert!((canonical * on_axis - p * on_axis).norm() < 1e-3);
        // Without symmetry, the pose itself.
        assert_eq!(Symmetry::default().canonical(&p), p);
    }

    #[test]
    fn the_closest_equivalent_is_found_through_the_symmetry() {
        let four = Symmetry::generated(&[element("z:4")]).unwrap();
        let target = pose([0.0; 3], Vector3::new(1.0, 0.0, 0.0), 0.3);
        let p = target * pose([0.0; 3], Vector3::z(), 3.0 * FRAC_PI_2 + 0.05);
        let found = four.closest_equivalent(&p, &target.rotation);
        assert!((found.rotation.angle_to(&target.rotation) - 0.05).abs() < 1e-4);
    }

    /// A symmetry of an object holds for the object scaled, scaled the same way.
    #[test]
    fn a_scaled_symmetry_is_that_of_the_scaled_object() {
        let s = Symmetry::generated(&[element("z:inf@1,2,0"), element("x:2@0,2,7")]).unwrap();
        let big = s.scaled(1000.0);
        let p = Point3::new(3.0, -1.0, 4.0);
        let (flip, flip_big) = (s.discrete[0], big.discrete[0]);
        assert!(((flip_big * (p * 1000.0)) - (flip * p) * 1000.0).norm() < 0.1);
        assert_eq!(
            big.continuous.unwrap().point_mm,
            Point3::new(1000.0, 2000.0, 0.0)
        );
        assert_eq!(s.scaled(1.0), s);
    }

    #[test]
    fn the_fixed_point_stays_under_every_symmetry() {
        let d = Symmetry::generated(&[element("z:3@1,2,0"), element("1,-2,0:2@1,2,7")]).unwrap();
        let c = Symmetry::generated(&[element("z:inf@1,2,0"), element("x:2@0,2,7")]).unwrap();
        for symmetry in [&d, &c] {
            let f = symmetry.fixed_point(&Point3::new(30.0, -4.0, 2.0));
            for s in &symmetry.discrete {
                assert!((s * f - f).norm() < 1e-3, "{symmetry:?}");
            }
            if let Some(axis) = &symmetry.continuous {
                assert!((axis.turn(1.0) * f - f).norm() < 1e-3);
            }
        }
        let p = Point3::new(1.0, 2.0, 3.0);
        assert_eq!(Symmetry::default().fixed_point(&p), p);
    }

    #[test]
    fn symmetries_and_turns_are_described_for_a_person() {
        assert_eq!(Symmetry::default().describe(), "none");
        let half = Symmetry::generated(&[element("z:2")]).unwrap();
        assert_eq!(half.describe(), "discrete, 2 poses alike");
        // A half turn's axis comes out with either sign; it is shown one way.
        for axis in [Vector3::z(), -Vector3::z()] {
            let turn = pose([0.0; 3], axis, PI);
            assert_eq!(
                describe_turn(&turn),
                "a turn of 180° about (0.00, 0.00, 1.00)"
            );
        }
        let quarter = pose([0.0; 3], -Vector3::x(), FRAC_PI_2);
        assert_eq!(
            describe_turn(&quarter),
            "a turn of 90° about (-1.00, 0.00, 0.00)"
        );
        let shaft = Symmetry::generated(&[element("z:inf@1,2,0"), element("x:2@0,2,0")]).unwrap();
        assert_eq!(
            shaft.describe(),
            "continuous about the axis (0.000, 0.000, 1.000) through (1.0, 2.0, 0.0) mm, and \
             discrete, 2 poses alike per turn"
        );
    }

    #[test]
    fn the_stored_form_reads_back_and_bad_ones_are_refused() {
        let s = Symmetry::generated(&[element("z:inf@1,2,0"), element("x:2@0,2,0")]).unwrap();
        let back = Symmetry::from_stored(&s.stored_discrete(), &s.stored_continuous()).unwrap();
        assert_eq!(back, s);
        assert!(Symmetry::from_stored(&[[2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]], &[]).is_err());
        assert!(Symmetry::from_stored(&[], &[[0.0, 0.0, 2.0, 0.0, 0.0, 0.0]]).is_err());
        let axis = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        assert!(Symmetry::from_stored(&[], &[axis, axis]).is_err());
    }

    #[test]
    fn validation_refuses_what_no_object_has() {
        let far = Symmetry {
            discrete: vec![pose([500.0, 0.0, 0.0], Vector3::z(), PI)],
            continuous: None,
        };
        assert!(far
            .validate(100.0)
            .unwrap_err()
            .to_string()
            .contains("moves the model"));
        // A flip that turns the continuous axis by 90°.
        let crossed = Symmetry {
            discrete: vec![pose([0.0; 3], Vector3::x(), FRAC_PI_2)],
            continuous: Some(SymmetryAxis {
                direction: Vector3::z_axis(),
                point_mm: Point3::origin(),
            }),
        };
        assert!(crossed
            .validate(100.0)
            .unwrap_err()
            .to_string()
            .contains("moves the continuous axis"));
        let fine = Symmetry::generated(&[element("z:inf"), element("x:2")]).unwrap();
        assert!(fine.validate(100.0).is_ok());
    }

    #[test]
    fn pose_errors_are_measured_to_the_nearest_equivalent_pose() {
        let target = pose([10.0, 0.0, 500.0], Vector3::new(1.0, 2.0, 3.0), 0.7);
        // A turn about a continuous axis off the origin, and a half turn of a discrete one.
        let off_axis = SymmetryAxis {
            direction: Vector3::z_axis(),
            point_mm: Point3::new(5.0, -3.0, 0.0),
        };
        let continuous = Symmetry {
            discrete: Vec::new(),
            continuous: Some(off_axis),
        };
        let turned = target * off_axis.turn(1.3);
        let (dt, dr) = continuous.pose_errors(&turned, &target);
        assert!(dt < 1e-3 && dr < 0.05, "{dt} mm, {dr}°");
        let flip = pose([0.0; 3], Vector3::x(), PI);
        let discrete = Symmetry {
            discrete: vec![flip],
            continuous: None,
        };
        let (dt, dr) = discrete.pose_errors(&(target * flip), &target);
        assert!(dt < 1e-3 && dr < 0.05, "{dt} mm, {dr}°");
        // Without the symmetry, the same poses are far off.
        let none = Symmetry::default();
        assert!(none.pose_errors(&turned, &target).1 > 70.0);
        assert!(none.pose_errors(&(target * flip), &target).1 > 170.0);
        // A pose off by a shift stays off by it.
        let shifted =
            Pose::from_parts(Translation3::new(0.0, 4.0, 0.0), UnitQuaternion::identity()) * target;
        let (dt, dr) = continuous.pose_errors(&shifted, &target);
        assert!((dt - 4.0).abs() < 1e-3 && dr < 0.05, "{dt} mm, {dr}°");
    }
}
