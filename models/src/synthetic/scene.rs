//! Synthetic test scenes: meshes placed on a table, seen by a depth camera from above, with known
//! poses and optional Kinect-like sensor noise. Everything is deterministic from a `u64` seed.
//!
//! A [`SceneSpec`] (builder) lists the objects (each a [`Mesh`] with an object id and a
//! [`Placement`]), the clutter ([`Occluder`]s, explicit or random), the camera's range of viewpoints
//! and the [`NoiseModel`]; [`SceneSpec::build`] renders a [`SyntheticScene`]: a 16-bit depth frame
//! (1 mm per unit), the ground-truth pose of every object and how much of each is visible.
//! [`SyntheticScene::single`] is the short way to one object at a given pose, and
//! [`random_pose_in_view`] draws such poses. [`Rng`] is the small seeded generator behind it all.
//!
//! World frame: millimetres, z up, the table top is the plane z = 0 (a 1400 × 1000 mm table with a
//! floor 750 mm below it).
//!
//! ```
//! use ppfd_models::synthetic::{parts::Part, scene::SceneSpec};
//! let (bracket, gear) = (Part::LBracket.mesh(), Part::ToothedDisc.mesh());
//! let scene = SceneSpec::new(7).object(1, &bracket).object(3, &gear).clutter(2).build().unwrap();
//! assert_eq!(scene.ground_truth.len(), 2);
//! assert_eq!(scene.frame.depth.len(), 640 * 480);
//! ```

use std::f32::consts::{FRAC_PI_2, PI};

use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, SymmetricEigen, Translation3, Unit, UnitQuaternion,
    Vector3,
};

use crate::geometry::camera::{Intrinsics, OwnedDepthFrame};
use crate::geometry::mesh::Mesh;
use crate::geometry::render::{render_scene, DepthImage, Renderer, Roi, NO_OBJECT};
use crate::synthetic::parts::{box_mesh, cylinder_mesh};
use crate::{Error, Pose, Result};

pub use crate::geometry::rng::Rng;

/// Kinect-v1-like depth noise, applied to the rendered depth before it is quantised to 1 mm.
/// Defaults follow Nguyen et al. (2012) for the axial term and what the real LM-O frames show for
/// the rest.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// Axial noise at 1 m, mm; σ grows with the square of the depth: `σ = k (z / 1 m)²`.
    /// Default 1.5 mm.
    pub axial_sigma_at_1m_mm: f32,
    /// Add Nguyen's grazing-angle term `0.1 mm / sqrt(z / 1 m) · θ² / (π/2 − θ)²` (θ between the
    /// surface normal and the viewing ray). Default on.
    pub grazing_term: bool,
    /// Upper bound of σ, mm. Default 8 mm.
    pub max_sigma_mm: f32,
    /// A pixel is on a depth edge when a neighbour within `edge_radius_px` (Chebyshev distance)
    /// has no depth or differs by more than this. Default 20 mm.
    pub edge_jump_mm: f32,
    /// Neighbourhood of the edge test. Default 1 px.
    pub edge_radius_px: u32,
    /// Probability that an edge pixel loses its depth. Default 0.5.
    pub edge_dropout: f32,
    /// Probability that any pixel loses its depth. Default 0.002.
    pub random_dropout: f32,
    /// Depths outside this range are not measured (Kinect v1: 0.4–3.5 m).
    pub range_mm: (f32, f32),
}

impl Default for NoiseModel {
    fn default() -> Self {
        NoiseModel {
            axial_sigma_at_1m_mm: 1.5,
            grazing_term: true,
            max_sigma_mm: 8.0,
            edge_jump_mm: 20.0,
            edge_radius_px: 1,
            edge_dropout: 0.5,
            random_dropout: 0.002,
            range_mm: (400.0, 3500.0),
        }
    }
}

impl NoiseModel {
    /// The default model (Kinect v1).
    pub fn kinect() -> NoiseModel {
        NoiseModel::default()
    }

    /// Axial σ (mm) at depth `z_mm` for a surface seen at angle `theta` (rad) from its normal.
    fn sigma_mm(&self, z_mm: f32, theta: f32) -> f32 {
        let z_m = z_mm / 1000.0;
        let mut sigma = self.axial_sigma_at_1m_mm * z_m * z_m;
        if self.grazing_term {
            let theta = theta.clamp(0.0, FRAC_PI_2 - 1e-3);
            sigma += 0.1 / z_m.sqrt() * theta * theta / ((FRAC_PI_2 - theta) * (FRAC_PI_2 - theta));
        }
        sigma.min(self.max_sigma_mm)
    }

    fn validate(&self) -> Result<()> {
        let probability = |p: f32| (0.0..=1.0).contains(&p);
        let ok = self.axial_sigma_at_1m_mm >= 0.0
            && self.max_sigma_mm >= 0.0
            && self.edge_jump_mm > 0.0
            && probability(self.edge_dropout)
            && probability(self.random_dropout)
            && self.range_mm.0 <= self.range_mm.1;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidParameter(format!(
                "noise model needs non-negative sigmas, a positive edge jump, probabilities in [0, 1] \
                 and an ordered range, got {self:?}"
            )))
        }
    }

    /// Applies the noise to a clean depth image (mm, 0 = none) in place.
    fn apply(&self, depth: &mut DepthImage, intrinsics: &Intrinsics, rng: &mut Rng) -> Result<()> {
        self.validate()?;
        intrinsics.validate_for(depth.width, depth.height)?;
        let (w, h) = (depth.width as usize, depth.height as usize);
        let clean = depth.depth_mm.clone();
        let at = |u: usize, v: usize| clean[v * w + u];
        let r = self.edge_radius_px as isize;
        let mut edge_rng = rng.fork();
        let mut axial_rng = rng.fork();
        let mut drop_rng = rng.fork();
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                let z = clean[i];
                if z <= 0.0 {
                    continue;
                }
                // Depth discontinuities: the sensor loses many of them.
                let mut on_edge = false;
                'search: for dv in -r..=r {
                    for du in -r..=r {
                        let (uu, vv) = (u as isize + du, v as isize + dv);
                        if uu < 0 || vv < 0 || uu >= w as isize || vv >= h as isize {
                            continue;
                        }
                        let zn = at(uu as usize, vv as usize);
                        if zn <= 0.0 || (zn - z).abs() > self.edge_jump_mm {
                            on_edge = true;
                            break 'search;
                        }
                    }
                }
                let edge_draw = edge_rng.uniform() as f32;
                let drop_draw = drop_rng.uniform() as f32;
                let noise = axial_rng.normal() as f32;
                if (on_edge && edge_draw < self.edge_dropout)
                    || drop_draw < self.random_dropout
                    || z < self.range_mm.0
                    || z > self.range_mm.1
                {
                    depth.depth_mm[i] = 0.0;
                    continue;
                }
                let theta = if self.grazing_term {
                    view_angle(&clean, w, h, u, v, intrinsics, self.edge_jump_mm)
                } else {
                    0.0
                };
                depth.depth_mm[i] = (z + self.sigma_mm(z, theta) * noise).max(0.0);
            }
        }
        Ok(())
    }
}

/// Angle between the surface normal (from the clean depth's central differences) and the viewing
/// ray at pixel `(u, v)`; 0 where a neighbour is missing or across an edge.
fn view_angle(
    depth: &[f32],
    w: usize,
    h: usize,
    u: usize,
    v: usize,
    k: &Intrinsics,
    jump: f32,
) -> f32 {
    if u == 0 || v == 0 || u + 1 >= w || v + 1 >= h {
        return 0.0;
    }
    let z = depth[v * w + u];
    let point = |uu: usize, vv: usize| {
        let zn = depth[vv * w + uu];
        (zn > 0.0 && (zn - z).abs() <= jump).then(|| k.backproject(uu as f32, vv as f32, zn))
    };
    let (Some(l), Some(r), Some(t), Some(b)) = (
        point(u - 1, v),
        point(u + 1, v),
        point(u, v - 1),
        point(u, v + 1),
    ) else {
        return 0.0;
    };
    let n = (r - l).cross(&(b - t));
    let ray = k.backproject(u as f32, v as f32, z).coords;
    let cos = (n.dot(&ray).abs() / (n.norm() * ray.norm())).clamp(0.0, 1.0);
    if cos.is_finite() {
        cos.acos()
    } else {
        0.0
    }
}

/// How an object is put into the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Placement {
    /// Resting on the table: one of the six faces of its principal-axis box down (flatter ways
    /// up are likelier), a random yaw, lowered until its lowest vertex is 0.5 mm above the table,
    /// at a free spot.
    Resting,
    /// A uniformly random rotation, lowered onto the table at a free spot.
    RandomRotation,
    /// Exactly this model → world pose (it may float or cut through the table).
    At(Pose),
}

/// A distractor solid in the scene. Poses map the solid's own frame (centred on it, a cylinder's
/// axis along z) into the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Occluder {
    /// A rectangular box.
    Box {
        /// Edge lengths along its x, y and z, mm.
        size_mm: Vector3<f32>,
        /// Its frame into the world.
        pose: Pose,
    },
    /// A closed cylinder with its axis along z.
    Cylinder {
        /// Radius, mm.
        radius_mm: f32,
        /// Length along the axis, mm.
        height_mm: f32,
        /// Its frame into the world.
        pose: Pose,
    },
}

impl Occluder {
    fn mesh_and_pose(&self) -> (Mesh, Pose) {
        match *self {
            Occluder::Box { size_mm, pose } => (box_mesh(size_mm), pose),
            Occluder::Cylinder {
                radius_mm,
                height_mm,
                pose,
            } => (cylinder_mesh(radius_mm, height_mm, 32), pose),
        }
    }
}

struct SceneObject<'a> {
    object_id: u32,
    mesh: &'a Mesh,
    placement: Placement,
}

/// The recipe of a synthetic scene. Start with [`SceneSpec::new`], add objects, then
/// [`build`](SceneSpec::build). Defaults mirror the LM-O capture setup.
pub struct SceneSpec<'a> {
    seed: u64,
    objects: Vec<SceneObject<'a>>,
    occluders: Vec<Occluder>,
    clutter: usize,
    camera_distance_mm: (f32, f32),
    elevation_deg: (f32, f32),
    azimuth_deg: (f32, f32),
    camera: Option<Pose>,
    noise: Option<NoiseModel>,
    table: bool,
    intrinsics: Intrinsics,
    width: u32,
    height: u32,
}

impl<'a> SceneSpec<'a> {
    /// An empty scene drawn from `seed`: camera 600–1200 mm from the objects at 20–70° elevation
    /// and any azimuth, LM-O intrinsics at 640×480, a table, no clutter, no noise.
    pub fn new(seed: u64) -> SceneSpec<'a> {
        SceneSpec {
            seed,
            objects: Vec::new(),
            occluders: Vec::new(),
            clutter: 0,
            camera_distance_mm: (600.0, 1200.0),
            elevation_deg: (20.0, 70.0),
            azimuth_deg: (-180.0, 180.0),
            camera: None,
            noise: None,
            table: true,
            intrinsics: Intrinsics::LMO,
            width: 640,
            height: 480,
        }
    }

    /// Adds an object resting on the table ([`Placement::Resting`]).
    pub fn object(self, object_id: u32, mesh: &'a Mesh) -> Self {
        self.object_with(object_id, mesh, Placement::Resting)
    }

    /// Adds an object placed as given.
    pub fn object_with(mut self, object_id: u32, mesh: &'a Mesh, placement: Placement) -> Self {
        self.objects.push(SceneObject {
            object_id,
            mesh,
            placement,
        });
        self
    }

    /// Adds this many random boxes (40–160 × 40–160 × 20–130 mm) and cylinders (radius 20–55 mm,
    /// height 40–180 mm, lying down one time in three) on the table around the objects.
    pub fn clutter(mut self, count: usize) -> Self {
        self.clutter = count;
        self
    }

    /// Adds one distractor exactly where given.
    pub fn occluder(mut self, occluder: Occluder) -> Self {
        self.occluders.push(occluder);
        self
    }

    /// Range of the camera's distance to the objects' centre, mm. Default 600–1200.
    pub fn camera_distance_mm(mut self, min: f32, max: f32) -> Self {
        self.camera_distance_mm = (min, max);
        self
    }

    /// Range of the camera's elevation above the table plane, degrees. Default 20–70.
    pub fn elevation_deg(mut self, min: f32, max: f32) -> Self {
        self.elevation_deg = (min, max);
        self
    }

    /// Range of the camera's azimuth around the objects, degrees. Default all around.
    pub fn azimuth_deg(mut self, min: f32, max: f32) -> Self {
        self.azimuth_deg = (min, max);
        self
    }

    /// Uses this world → camera pose instead of drawing a viewpoint.
    pub fn camera(mut self, world_to_camera: Pose) -> Self {
        self.camera = Some(world_to_camera);
        self
    }

    /// Sensor noise, or `None` for exact depth (still quantised to 1 mm). Default none.
    pub fn noise(mut self, noise: Option<NoiseModel>) -> Self {
        self.noise = noise;
        self
    }

    /// Whether to draw the table and the floor. Default on.
    pub fn table(mut self, table: bool) -> Self {
        self.table = table;
        self
    }

    /// Another camera. Default LM-O, 640×480.
    pub fn intrinsics(mut self, intrinsics: Intrinsics, width: u32, height: u32) -> Self {
        self.intrinsics = intrinsics;
        self.width = width;
        self.height = height;
        self
    }

    fn validate(&self) -> Result<()> {
        let range = |(lo, hi): (f32, f32)| lo.is_finite() && hi.is_finite() && lo <= hi;
        if self.objects.is_empty() {
            return Err(Error::InvalidParameter(
                "a synthetic scene needs at least one object".into(),
            ));
        }
        for o in &self.objects {
            check_mesh(o.mesh, o.object_id)?;
        }
        if !range(self.camera_distance_mm) || self.camera_distance_mm.0 <= 0.0 {
            return Err(Error::InvalidParameter(format!(
                "camera distance range must be positive and ordered, got {:?} mm",
                self.camera_distance_mm
            )));
        }
        if !range(self.elevation_deg) || self.elevation_deg.0 < 0.0 || self.elevation_deg.1 >= 90.0
        {
            return Err(Error::InvalidParameter(format!(
                "camera elevation range must be ordered within [0, 90) degrees, got {:?}",
                self.elevation_deg
            )));
        }
        if !range(self.azimuth_deg) {
            return Err(Error::InvalidParameter(format!(
                "azimuth range must be ordered, got {:?}",
                self.azimuth_deg
            )));
        }
        if self.width == 0 || self.height == 0 {
            return Err(Error::InvalidParameter(format!(
                "image size must be positive, got {}x{}",
                self.width, self.height
            )));
        }
        if let Some(noise) = &self.noise {
            noise.validate()?;
        }
        self.intrinsics.validate_for(self.width, self.height)
    }

    /// Places everything, renders, adds noise.
    pub fn build(&self) -> Result<SyntheticScene> {
        self.validate()?;
        let mut rng = Rng::new(self.seed);
        let mut place_rng = rng.fork();
        let mut clutter_rng = rng.fork();
        let mut camera_rng = rng.fork();
        let mut noise_rng = rng.fork();

        // Objects: free ones are put on spots in a rectangle that grows when it is crowded.
        let mut model_to_world = Vec::with_capacity(self.objects.len());
        let mut footprints: Vec<(nalgebra::Vector2<f32>, f32)> = Vec::new();
        for o in &self.objects {
            if let Placement::At(pose) = o.placement {
                let (c, r) = crate::geometry::render::bounding_sphere(o.mesh);
                let c = pose * c;
                footprints.push((nalgebra::Vector2::new(c.x, c.y), r));
            }
        }
        let free = self
            .objects
            .iter()
            .filter(|o| !matches!(o.placement, Placement::At(_)))
            .count();
        let mut half = nalgebra::Vector2::new(140.0f32, 105.0) * (free.max(1) as f32 / 4.0).sqrt();
        for o in &self.objects {
            let rotation = match o.placement {
                Placement::At(pose) => {
                    model_to_world.push(pose);
                    continue;
                }
                Placement::Resting => resting_rotation(o.mesh, &mut place_rng),
                Placement::RandomRotation => place_rng.rotation(),
            };
            let (offset, radius, lift) = footprint(o.mesh, &rotation);
            let centre = free_spot(&mut place_rng, &mut half, radius, &footprints);
            footprints.push((centre, radius));
            let t = Vector3::new(centre.x - offset.x, centre.y - offset.y, lift + 0.5);
            model_to_world.push(Isometry3::from_parts(Translation3::from(t), rotation));
        }

        // Clutter around the objects.
        let mut occluders = self.occluders.clone();
        let mut clutter_half = nalgebra::Vector2::new(260.0f32, 200.0);
        for _ in 0..self.clutter {
            let yaw =
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), clutter_rng.range(-PI, PI));
            let (occluder, radius) = if clutter_rng.uniform() < 0.5 {
                let size = Vector3::new(
                    clutter_rng.range(40.0, 160.0),
                    clutter_rng.range(40.0, 160.0),
                    clutter_rng.range(20.0, 130.0),
                );
                (
                    Occluder::Box {
                        size_mm: size,
                        pose: Isometry3::from_parts(Translation3::new(0.0, 0.0, size.z / 2.0), yaw),
                    },
                    size.xy().norm() / 2.0,
                )
            } else {
                let (r, h) = (
                    clutter_rng.range(20.0, 55.0),
                    clutter_rng.range(40.0, 180.0),
                );
                if clutter_rng.uniform() < 1.0 / 3.0 {
                    let lying =
                        yaw * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2);
                    let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, r), lying);
                    (
                        Occluder::Cylinder {
                            radius_mm: r,
                            height_mm: h,
                            pose,
                        },
                        (r * r + h * h / 4.0).sqrt(),
                    )
                } else {
                    let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, h / 2.0), yaw);
                    (
                        Occluder::Cylinder {
                            radius_mm: r,
                            height_mm: h,
                            pose,
                        },
                        r,
                    )
                }
            };
            let centre = free_spot(&mut clutter_rng, &mut clutter_half, radius, &footprints);
            footprints.push((centre, radius));
            let moved = |mut pose: Pose| {
                pose.translation.vector.x += centre.x;
                pose.translation.vector.y += centre.y;
                pose
            };
            occluders.push(match occluder {
                Occluder::Box { size_mm, pose } => Occluder::Box {
                    size_mm,
                    pose: moved(pose),
                },
                Occluder::Cylinder {
                    radius_mm,
                    height_mm,
                    pose,
                } => Occluder::Cylinder {
                    radius_mm,
                    height_mm,
                    pose: moved(pose),
                },
            });
        }

        // Camera: looks at the objects' centre from a random viewpoint above the table.
        let world_to_camera = match self.camera {
            Some(pose) => pose,
            None => {
                let mut target = Vector3::zeros();
                for pose in &model_to_world {
                    target += pose.translation.vector;
                }
                target /= model_to_world.len() as f32;
                target += Vector3::new(
                    camera_rng.range(-30.0, 30.0),
                    camera_rng.range(-30.0, 30.0),
                    0.0,
                );
                let distance =
                    camera_rng.range(self.camera_distance_mm.0, self.camera_distance_mm.1);
                let elevation = camera_rng
                    .range(self.elevation_deg.0, self.elevation_deg.1)
                    .to_radians();
                let azimuth = camera_rng
                    .range(self.azimuth_deg.0, self.azimuth_deg.1)
                    .to_radians();
                let roll = camera_rng.range(-5.0, 5.0).to_radians();
                look_at(&Point3::from(target), distance, elevation, azimuth, roll)
            }
        };

        let mut extra: Vec<(Mesh, Pose)> = Vec::new();
        if self.table {
            let table = box_mesh(Vector3::new(1400.0, 1000.0, 30.0));
            extra.push((table, Isometry3::translation(0.0, 0.0, -15.0)));
            let floor = box_mesh(Vector3::new(8000.0, 8000.0, 10.0));
            extra.push((floor, Isometry3::translation(0.0, 0.0, -755.0)));
        }
        extra.extend(occluders.iter().map(Occluder::mesh_and_pose));
        let ground_truth: Vec<(u32, Pose)> = self
            .objects
            .iter()
            .zip(&model_to_world)
            .map(|(o, m2w)| (o.object_id, world_to_camera * m2w))
            .collect();
        let mut all: Vec<(&Mesh, Pose)> = self
            .objects
            .iter()
            .zip(&ground_truth)
            .map(|(o, gt)| (o.mesh, gt.1))
            .collect();
        all.extend(extra.iter().map(|(m, p)| (m, world_to_camera * p)));
        compose(
            &all,
            ground_truth,
            world_to_camera,
            &self.intrinsics,
            self.width,
            self.height,
            self.noise.as_ref(),
            &mut noise_rng,
        )
    }
}

/// A rendered synthetic scene with its ground truth.
#[derive(Clone, Debug)]
pub struct SyntheticScene {
    /// The depth frame: 16-bit, 1 mm per unit (`depth_scale_mm` 1.0), 0 = no measurement.
    pub frame: OwnedDepthFrame,
    /// Object id and model → camera pose of every object, in the order they were added.
    pub ground_truth: Vec<(u32, Pose)>,
    /// Per object: pixels where it is seen in the scene / pixels it covers rendered alone (before
    /// noise); 0 for an object out of view.
    pub visible_fraction: Vec<f32>,
    /// Per pixel, the index into `ground_truth` of the object seen there (before noise), or
    /// [`NO_OBJECT`] for table, clutter and background.
    pub object_index: Vec<u32>,
    /// World (table) → camera pose; identity for [`SyntheticScene::single`].
    pub world_to_camera: Pose,
}

impl SyntheticScene {
    /// The ground-truth pose of the first object with `object_id`.
    pub fn truth_of(&self, object_id: u32) -> Option<Pose> {
        self.ground_truth
            .iter()
            .find(|(id, _)| *id == object_id)
            .map(|&(_, pose)| pose)
    }

    /// Every generated part ([`Part::ALL`](crate::synthetic::parts::Part::ALL)), once each,
    /// resting on a table seen from a viewpoint drawn from `seed`, with `noise`: with
    /// Kinect-like noise, the scene `ppf demo --seed` shows and `ppf generate --seed` writes.
    pub fn of_every_part(seed: u64, noise: Option<NoiseModel>) -> Result<SyntheticScene> {
        use crate::synthetic::parts::Part;
        let meshes: Vec<Mesh> = Part::ALL.iter().map(Part::mesh).collect();
        let objects: Vec<(u32, &Mesh)> =
            Part::ALL.iter().map(Part::object_id).zip(&meshes).collect();
        SyntheticScene::resting(seed, noise, 0, &objects)
    }

    /// `objects` (object id, mesh in mm), once each, resting on a table among `clutter` random
    /// boxes and cylinders ([`SceneSpec::clutter`]), seen from a viewpoint drawn from `seed`,
    /// with `noise`: the recipe of [`SyntheticScene::of_every_part`] for any meshes, which
    /// `ppf generate --models` writes.
    pub fn resting(
        seed: u64,
        noise: Option<NoiseModel>,
        clutter: usize,
        objects: &[(u32, &Mesh)],
    ) -> Result<SyntheticScene> {
        let mut spec = SceneSpec::new(seed).noise(noise).clutter(clutter);
        for &(id, mesh) in objects {
            spec = spec.object(id, mesh);
        }
        spec.build()
    }

    /// One object at `pose` (model → camera) in front of the LM-O camera at 640×480, nothing else
    /// in view; `noise` as for [`SceneSpec::noise`], drawn from `seed`.
    pub fn single(
        mesh: &Mesh,
        object_id: u32,
        pose: Pose,
        noise: Option<&NoiseModel>,
        seed: u64,
    ) -> Result<SyntheticScene> {
        check_mesh(mesh, object_id)?;
        if let Some(noise) = noise {
            noise.validate()?;
        }
        let mut rng = Rng::new(seed);
        compose(
            &[(mesh, pose)],
            vec![(object_id, pose)],
            Pose::identity(),
            &Intrinsics::LMO,
            640,
            480,
            noise,
            &mut rng,
        )
    }
}

fn check_mesh(mesh: &Mesh, object_id: u32) -> Result<()> {
    if mesh.faces.is_empty() {
        return Err(Error::InvalidMesh(format!(
            "object {object_id} has no faces to render"
        )));
    }
    if let Some(p) = mesh
        .positions
        .iter()
        .find(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(Error::InvalidMesh(format!(
            "object {object_id} has a vertex at {p:?}; positions must be finite"
        )));
    }
    Ok(())
}

/// Renders the scene (the first `ground_truth.len()` entries of `all` are the objects), measures
/// visibility, adds noise and quantises.
#[allow(clippy::too_many_arguments)]
fn compose(
    all: &[(&Mesh, Pose)],
    ground_truth: Vec<(u32, Pose)>,
    world_to_camera: Pose,
    intrinsics: &Intrinsics,
    width: u32,
    height: u32,
    noise: Option<&NoiseModel>,
    rng: &mut Rng,
) -> Result<SyntheticScene> {
    let n_objects = ground_truth.len();
    let scene = render_scene(all, intrinsics, width, height)?;
    let object_index: Vec<u32> = scene
        .object_index
        .iter()
        .map(|&i| {
            if (i as usize) < n_objects {
                i
            } else {
                NO_OBJECT
            }
        })
        .collect();
    let mut visible = vec![0usize; n_objects];
    for &i in &object_index {
        if i != NO_OBJECT {
            visible[i as usize] += 1;
        }
    }
    let mut renderer = Renderer::new();
    let mut visible_fraction = Vec::with_capacity(n_objects);
    for (i, (mesh, pose)) in all[..n_objects].iter().enumerate() {
        renderer.render_into(mesh, pose, intrinsics, Roi::full(width, height))?;
        let alone = renderer.depth_mm().iter().filter(|&&d| d > 0.0).count();
        visible_fraction.push(if alone == 0 {
            0.0
        } else {
            visible[i] as f32 / alone as f32
        });
    }
    let mut depth = scene.depth;
    if let Some(noise) = noise {
        noise.apply(&mut depth, intrinsics, rng)?;
    }
    let frame = depth.to_frame(*intrinsics, 1.0)?;
    Ok(SyntheticScene {
        frame,
        ground_truth,
        visible_fraction,
        object_index,
        world_to_camera,
    })
}

/// A random model → camera pose that keeps an object of `diameter_mm` inside the LM-O camera's
/// 640×480 view: uniformly random rotation, depth uniform in `distance_range_mm`, image position
/// uniform over the pixels where the whole bounding sphere stays in view (centred when it cannot).
pub fn random_pose_in_view(rng: &mut Rng, diameter_mm: f32, distance_range_mm: (f32, f32)) -> Pose {
    let k = Intrinsics::LMO;
    let (w, h) = (640.0f32, 480.0f32);
    let (lo, hi) = distance_range_mm;
    let z = rng.range(lo.min(hi), lo.max(hi)).max(1.0);
    let radius = diameter_mm.abs() / 2.0;
    let pick = |rng: &mut Rng, size: f32, f: f32, c: f32| {
        let margin = f * radius / (z - radius).max(1.0) + 2.0;
        let pixel = if 2.0 * margin < size {
            rng.range(margin, size - margin)
        } else {
            c
        };
        (pixel - c) * z / f
    };
    let x = pick(rng, w, k.fx, k.cx);
    let y = pick(rng, h, k.fy, k.cy);
    Isometry3::from_parts(Translation3::new(x, y, z), rng.rotation())
}

/// World → camera pose of a camera `distance` from `target`, at `elevation` above the horizontal
/// and `azimuth` around the vertical, looking at the target (image "up" toward world +z), turned
/// by `roll` about its optical axis.
fn look_at(target: &Point3<f32>, distance: f32, elevation: f32, azimuth: f32, roll: f32) -> Pose {
    let dir = Vector3::new(
        elevation.cos() * azimuth.cos(),
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
    );
    let eye = target + dir * distance;
    let z = -dir;
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let rows = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), roll)
        * Rotation3::from_matrix_unchecked(rows);
    let rotation = UnitQuaternion::from_rotation_matrix(&rotation);
    Isometry3::from_parts(Translation3::from(-(rotation * eye.coords)), rotation)
}

/// A resting orientation: a principal axis of the vertices pointing down (weighted toward flat
/// ways of lying), then a random yaw.
fn resting_rotation(mesh: &Mesh, rng: &mut Rng) -> UnitQuaternion<f32> {
    let n = mesh.positions.len().max(1) as f32;
    let mean = mesh
        .positions
        .iter()
        .fold(Vector3::zeros(), |s, p| s + p.coords)
        / n;
    let cov = mesh.positions.iter().fold(Matrix3::zeros(), |s, p| {
        let d = p.coords - mean;
        s + d * d.transpose()
    }) / n;
    let axes = SymmetricEigen::new(cov).eigenvectors;
    let extent = |a: &Vector3<f32>| {
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for p in &mesh.positions {
            let t = p.coords.dot(a);
            lo = lo.min(t);
            hi = hi.max(t);
        }
        (hi - lo).max(1e-3)
    };
    let ext: Vec<f32> = (0..3)
        .map(|k| extent(&axes.column(k).into_owned()))
        .collect();
    let weights: Vec<f32> = (0..3)
        .map(|k| ext[(k + 1) % 3] * ext[(k + 2) % 3] / ext[k])
        .collect();
    let total: f32 = weights.iter().sum();
    let mut pick = rng.range(0.0, total);
    let mut k = 2;
    for (i, w) in weights.iter().enumerate() {
        if pick < *w {
            k = i;
            break;
        }
        pick -= w;
    }
    let sign = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
    let down = Unit::new_normalize(axes.column(k).into_owned() * sign);
    let to_floor = UnitQuaternion::rotation_between_axis(&down, &-Vector3::z_axis())
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI));
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.range(-PI, PI)) * to_floor
}

/// For a mesh turned by `rotation`: the centre of its xy bounding box, the radius of the circle
/// around it holding every vertex, and how far to lift it so its lowest vertex is at z = 0.
fn footprint(mesh: &Mesh, rotation: &UnitQuaternion<f32>) -> (nalgebra::Vector2<f32>, f32, f32) {
    let turned: Vec<Vector3<f32>> = mesh.positions.iter().map(|p| rotation * p.coords).collect();
    let (mut lo, mut hi) = (Vector3::repeat(f32::MAX), Vector3::repeat(f32::MIN));
    for p in &turned {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let c = nalgebra::Vector2::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0);
    let r = turned
        .iter()
        .map(|p| (p.xy() - c).norm())
        .fold(0.0f32, f32::max);
    (c, r, -lo.z)
}

/// A point in the rectangle `±half` whose circle of `radius` keeps 5 mm from every circle in
/// `taken`; the rectangle grows by a quarter after every 40 failed draws (after 30 growths the
/// last draw is taken as it is).
fn free_spot(
    rng: &mut Rng,
    half: &mut nalgebra::Vector2<f32>,
    radius: f32,
    taken: &[(nalgebra::Vector2<f32>, f32)],
) -> nalgebra::Vector2<f32> {
    let mut p = nalgebra::Vector2::zeros();
    for _ in 0..30 {
        for _ in 0..40 {
            p = nalgebra::Vector2::new(rng.range(-half.x, half.x), rng.range(-half.y, half.y));
            if taken
                .iter()
                .all(|(c, r)| (p - c).norm() >= r + radius + 5.0)
            {
                return p;
            }
        }
        *half *= 1.25;
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::render::render_depth;
    use crate::synthetic::parts::Part;

    fn parts() -> Vec<(u32, Mesh)> {
        Part::ALL
            .iter()
            .map(|p| (p.object_id(), p.mesh()))
            .collect()
    }

    #[test]
    fn rng_is_deterministic_and_roughly_normal() {
        let (mut a, mut b) = (Rng::new(42), Rng::new(42));
        for _ in 0..100 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        let mut r = Rng::new(1);
        let xs: Vec<f64> = (0..20_000).map(|_| r.normal()).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "mean {mean} var {var}"
        );
        let q = r.rotation();
        assert!((q.norm() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn ground_truth_projects_onto_scene_depth() {
        let parts = parts();
        let mut spec = SceneSpec::new(11).clutter(3);
        for (id, mesh) in &parts {
            spec = spec.object(*id, mesh);
        }
        let scene = spec.build().unwrap();
        let frame = scene.frame.view();
        for (index, ((id, pose), (_, mesh))) in scene.ground_truth.iter().zip(&parts).enumerate() {
            let alone = render_depth(mesh, pose, &Intrinsics::LMO, 640, 480).unwrap();
            let mut own = 0;
            for v in 0..480 {
                for u in 0..640 {
                    let Some(z_object) = alone.get(u, v) else {
                        continue;
                    };
                    // Where the object projects the scene has depth, never behind the object.
                    let z_scene = frame
                        .depth_mm(u, v)
                        .unwrap_or_else(|| panic!("object {id}: no depth at ({u},{v})"));
                    assert!(
                        z_scene <= z_object + 0.5,
                        "object {id} at ({u},{v}): scene {z_scene} behind {z_object}"
                    );
                    if scene.object_index[(v * 640 + u) as usize] == index as u32 {
                        // Seen directly: exact up to quantisation.
                        assert!(
                            (z_scene - z_object).abs() <= 0.5 + 1e-3,
                            "({u},{v}): {z_scene} vs {z_object}"
                        );
                        own += 1;
                    }
                }
            }
            let fraction = scene.visible_fraction[index];
            assert!(own > 100, "object {id} shows only {own} pixels");
            let alone_count = alone.foreground_count();
            assert!((fraction - own as f32 / alone_count as f32).abs() < 1e-6);
        }
    }

    #[test]
    fn resting_objects_sit_on_the_table_apart() {
        let parts = parts();
        for seed in 0..5 {
            let mut spec = SceneSpec::new(seed);
            for (id, mesh) in &parts {
                spec = spec.object(*id, mesh);
            }
            let scene = spec.build().unwrap();
            let camera_to_world = scene.world_to_camera.inverse();
            let mut circles = Vec::new();
            for ((_, pose), (_, mesh)) in scene.ground_truth.iter().zip(&parts) {
                let world: Vec<Point3<f32>> = mesh
                    .positions
                    .iter()
                    .map(|p| camera_to_world * (pose * p))
                    .collect();
                let lowest = world.iter().map(|p| p.z).fold(f32::MAX, f32::min);
                assert!(
                    (lowest - 0.5).abs() < 0.05,
                    "seed {seed}: lowest vertex at {lowest}"
                );
                let (mut lo, mut hi) = (world[0].xy(), world[0].xy());
                for p in &world {
                    lo = lo.inf(&p.xy());
                    hi = hi.sup(&p.xy());
                }
                let c = (lo.coords + hi.coords) / 2.0;
                let r = world
                    .iter()
                    .map(|p| (p.xy().coords - c).norm())
                    .fold(0.0f32, f32::max);
                circles.push((c, r));
            }
            for (i, a) in circles.iter().enumerate() {
                for b in &circles[i + 1..] {
                    let gap = (a.0 - b.0).norm() - a.1 - b.1;
                    assert!(gap > 4.9, "seed {seed}: footprints {gap} mm apart");
                }
            }
            assert!(
                scene.visible_fraction.iter().all(|&f| f > 0.0 && f <= 1.0),
                "{:?}",
                scene.visible_fraction
            );
        }
    }

    #[test]
    fn same_seed_same_frame() {
        let gear = Part::ToothedDisc.mesh();
        let tee = Part::TPipe.mesh();
        let build = |seed| {
            SceneSpec::new(seed)
                .object(3, &gear)
                .object_with(4, &tee, Placement::RandomRotation)
                .clutter(4)
                .noise(Some(NoiseModel::kinect()))
                .build()
                .unwrap()
        };
        let (a, b, c) = (build(5), build(5), build(6));
        assert_eq!(a.frame.depth, b.frame.depth);
        assert_eq!(a.ground_truth, b.ground_truth);
        assert_ne!(a.frame.depth, c.frame.depth);
    }

    #[test]
    fn an_occluder_between_camera_and_object_hides_part_of_it() {
        let mesh = Part::FlangedCylinder.mesh();
        // Camera 800 mm above the table looking straight down (elevation 90° is refused for random
        // viewpoints, but any fixed camera is allowed).
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI);
        let camera = Isometry3::from_parts(Translation3::new(0.0, 0.0, 800.0), down);
        let object = Isometry3::translation(0.0, 0.0, 45.5);
        let base = SceneSpec::new(3)
            .camera(camera)
            .object_with(2, &mesh, Placement::At(object));
        let clear = base.build().unwrap();
        assert_eq!(clear.visible_fraction, vec![1.0]);
        let lid = Occluder::Box {
            size_mm: Vector3::new(80.0, 200.0, 10.0),
            pose: Isometry3::translation(50.0, 0.0, 200.0),
        };
        let hidden = SceneSpec::new(3)
            .camera(camera)
            .object_with(2, &mesh, Placement::At(object))
            .occluder(lid)
            .build()
            .unwrap();
        let f = hidden.visible_fraction[0];
        assert!(f > 0.1 && f < 0.9, "visible fraction {f}");
        // The occluder's depth is what the frame sees in front of the object.
        let px = Intrinsics::LMO.project(&(camera * Point3::new(50.0, 0.0, 200.0)));
        let (u, v) = (px.x.round() as u32, px.y.round() as u32);
        assert_eq!(hidden.frame.view().depth_mm(u, v), Some(595.0));
    }

    #[test]
    fn noise_has_the_kinect_axial_spread_and_drops_edges() {
        // A large box face 1 m in front of the camera.
        let slab = box_mesh(Vector3::new(1200.0, 900.0, 50.0));
        let pose = Isometry3::translation(0.0, 0.0, 1025.0);
        let noise = NoiseModel {
            random_dropout: 0.0,
            ..NoiseModel::kinect()
        };
        let noisy = SyntheticScene::single(&slab, 9, pose, Some(&noise), 77).unwrap();
        let clean = SyntheticScene::single(&slab, 9, pose, None, 77).unwrap();
        let (mut sum, mut sum2, mut n) = (0.0f64, 0.0f64, 0usize);
        for v in 50..430 {
            for u in 50..590 {
                let i = (v * 640 + u) as usize;
                assert_eq!(clean.frame.depth[i], 1000);
                let d = noisy.frame.depth[i] as f64 - 1000.0;
                sum += d;
                sum2 += d * d;
                n += 1;
            }
        }
        let (mean, sd) = (
            sum / n as f64,
            (sum2 / n as f64 - (sum / n as f64).powi(2)).sqrt(),
        );
        // 1.5 mm axial noise plus 1 mm quantisation (σ² + 1/12).
        assert!(
            mean.abs() < 0.05 && (sd - 1.527).abs() < 0.08,
            "mean {mean} sd {sd}"
        );

        // A part in front of nothing: its silhouette loses about half its pixels.
        let part = Part::LBracket.mesh();
        let pose = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 700.0),
            UnitQuaternion::from_euler_angles(0.3, 0.4, 0.2),
        );
        let noise = NoiseModel {
            random_dropout: 0.0,
            axial_sigma_at_1m_mm: 0.0,
            grazing_term: false,
            ..NoiseModel::kinect()
        };
        let noisy = SyntheticScene::single(&part, 1, pose, Some(&noise), 3).unwrap();
        let clean = SyntheticScene::single(&part, 1, pose, None, 3).unwrap();
        let (mut edge, mut edge_dropped, mut inner, mut inner_dropped) = (0, 0, 0, 0);
        for v in 1..479u32 {
            for u in 1..639u32 {
                let i = (v * 640 + u) as usize;
                if clean.frame.depth[i] == 0 {
                    continue;
                }
                let on_edge = [
                    (u - 1, v),
                    (u + 1, v),
                    (u, v - 1),
                    (u, v + 1),
                    (u - 1, v - 1),
                    (u + 1, v + 1),
                    (u - 1, v + 1),
                    (u + 1, v - 1),
                ]
                .iter()
                .any(|&(a, b)| {
                    let zn = clean.frame.depth[(b * 640 + a) as usize] as f32;
                    zn == 0.0 || (zn - clean.frame.depth[i] as f32).abs() > 20.0
                });
                let dropped = noisy.frame.depth[i] == 0;
                if on_edge {
                    edge += 1;
                    edge_dropped += dropped as usize;
                } else {
                    inner += 1;
                    inner_dropped += dropped as usize;
                }
            }
        }
        let edge_rate = edge_dropped as f32 / edge as f32;
        assert!(
            edge > 200 && (edge_rate - 0.5).abs() < 0.1,
            "{edge_dropped} of {edge} edge pixels dropped"
        );
        assert_eq!(
            inner_dropped, 0,
            "{inner_dropped} of {inner} inner pixels dropped"
        );
    }

    #[test]
    fn random_poses_stay_in_view() {
        let mesh = Part::TPipe.mesh();
        let (_, radius) = crate::geometry::render::bounding_sphere(&mesh);
        let mut rng = Rng::new(9);
        for _ in 0..20 {
            let pose = random_pose_in_view(&mut rng, 2.0 * radius, (500.0, 1500.0));
            assert!((500.0..=1500.0).contains(&pose.translation.z));
            let image = render_depth(&mesh, &pose, &Intrinsics::LMO, 640, 480).unwrap();
            // Nothing touches the border: the whole object is in view.
            for u in 0..640 {
                assert!(image.get(u, 0).is_none() && image.get(u, 479).is_none());
            }
            for v in 0..480 {
                assert!(image.get(0, v).is_none() && image.get(639, v).is_none());
            }
            assert!(image.foreground_count() > 500);
        }
    }

    #[test]
    fn refuses_bad_specs() {
        assert!(SceneSpec::new(0).build().is_err());
        let mesh = Part::LBracket.mesh();
        assert!(SceneSpec::new(0)
            .object(1, &mesh)
            .elevation_deg(30.0, 95.0)
            .build()
            .is_err());
        assert!(SceneSpec::new(0)
            .object(1, &mesh)
            .camera_distance_mm(900.0, 600.0)
            .build()
            .is_err());
        let bad_noise = NoiseModel {
            edge_dropout: 1.5,
            ..NoiseModel::kinect()
        };
        assert!(SceneSpec::new(0)
            .object(1, &mesh)
            .noise(Some(bad_noise))
            .build()
            .is_err());
        assert!(SyntheticScene::single(&Mesh::default(), 1, Pose::identity(), None, 0).is_err());
        let mut broken = mesh.clone();
        broken.positions[0].x = f32::NAN;
        assert!(SceneSpec::new(0).object(1, &broken).build().is_err());
    }
}
