//! Depth rendering: a z-buffer rasteriser that draws meshes at poses into depth images, as
//! re-scoring, the filters and the evaluation (VSD) need, and as synthetic scenes are made.
//!
//! A [`Renderer`] owns its buffers and reuses them: [`Renderer::clear`] sets a region of interest
//! ([`Roi`], in full-image pixel coordinates) and [`Renderer::draw`] rasterises one mesh at one
//! pose into it; nothing is allocated per pixel or per triangle, and buffers only grow.
//! [`render_depth`] and [`render_scene`] are one-call conveniences that return a [`DepthImage`].
//!
//! Conventions: OpenCV camera, pixel centres at integer coordinates (the ray of pixel `(u, v)` is
//! `((u - cx)/fx, (v - cy)/fy, 1)`), depth is camera z in millimetres, 0 is background.
//!
//! How: vertices are transformed and projected once per draw; triangles are clipped against the
//! near plane (and, far outside the image, against a guard band) in camera space, snapped to 1/256
//! pixel and scanned over their bounding box with exact integer edge functions and a top-left fill
//! rule, so triangles that share an edge neither leave gaps nor overlap. Depth is not interpolated
//! from the snapped vertices: each pixel's depth is the exact intersection of its ray with the
//! triangle's plane (1/z is affine in pixel coordinates), clamped to the triangle's depth range.
//!
//! ```
//! use nalgebra::{Isometry3, Vector3};
//! use ppfd_models::geometry::{camera::Intrinsics, render::render_depth};
//! use ppfd_models::synthetic::parts::Part;
//! let pose = Isometry3::translation(0.0, 0.0, 1000.0);
//! let image = render_depth(&Part::FlangedCylinder.mesh(), &pose, &Intrinsics::LMO, 640, 480).unwrap();
//! assert!(image.foreground_count() > 1000);
//! ```

use nalgebra::{Matrix3, Point3, Vector3};

use crate::geometry::camera::{Intrinsics, OwnedDepthFrame};
use crate::geometry::mesh::Mesh;
use crate::{Error, Pose, Result};

/// The object index of pixels no object covers.
pub const NO_OBJECT: u32 = u32::MAX;

/// Default near clipping distance: surfaces closer to the camera than this are not drawn.
pub const DEFAULT_NEAR_MM: f32 = 1.0;

/// Sub-pixel precision of the snapped vertex coordinates (8 bits, as GPUs use).
const SUBPIXEL: f32 = 256.0;
const SUBPIXEL_I: i64 = 256;
const SUBPIXEL_BITS: u32 = 8;
/// Triangles reaching further than this outside the region of interest are clipped, which keeps
/// the fixed-point edge functions far from overflow.
const GUARD_PX: f32 = 4096.0;
/// Images larger than this (in either direction) are refused: it keeps fixed-point pixel
/// coordinates within `i32`.
const MAX_IMAGE_PX: u64 = 1 << 20;
/// Marks a vertex that cannot take the fast path (behind the near plane or outside the guard band).
const OFF_SCREEN: i32 = i32::MIN;

/// A depth image in millimetres (camera z), row-major; 0.0 is background.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Per pixel, row-major, camera z in mm; 0.0 is background.
    pub depth_mm: Vec<f32>,
}

impl DepthImage {
    /// An image with no foreground.
    pub fn new(width: u32, height: u32) -> DepthImage {
        DepthImage {
            width,
            height,
            depth_mm: vec![0.0; width as usize * height as usize],
        }
    }

    /// Depth at pixel `(u, v)`, or `None` for background and outside the image.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> Option<f32> {
        if u >= self.width || v >= self.height {
            return None;
        }
        let d = self.depth_mm[(v * self.width + u) as usize];
        (d > 0.0).then_some(d)
    }

    /// How many pixels have depth.
    pub fn foreground_count(&self) -> usize {
        self.depth_mm.iter().filter(|&&d| d > 0.0).count()
    }

    /// Quantises into a 16-bit depth frame (`raw = round(z / depth_scale_mm)`); depths that do
    /// not fit 16 bits become 0 (no measurement), as a sensor out of range reports.
    pub fn to_frame(&self, intrinsics: Intrinsics, depth_scale_mm: f32) -> Result<OwnedDepthFrame> {
        if !(depth_scale_mm.is_finite() && depth_scale_mm > 0.0) {
            return Err(Error::InvalidParameter(format!(
                "depth scale must be finite and positive, got {depth_scale_mm}"
            )));
        }
        let depth = self
            .depth_mm
            .iter()
            .map(|&z| {
                let raw = (z / depth_scale_mm).round();
                if raw > 0.0 && raw <= u16::MAX as f32 {
                    raw as u16
                } else {
                    0
                }
            })
            .collect();
        Ok(OwnedDepthFrame {
            width: self.width,
            height: self.height,
            intrinsics,
            depth_scale_mm,
            depth,
        })
    }
}

/// A rectangle of pixels `[u0, u0 + width) × [v0, v0 + height)` in full-image coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Roi {
    /// First column, full-image pixels.
    pub u0: u32,
    /// First row, full-image pixels.
    pub v0: u32,
    /// Columns, pixels.
    pub width: u32,
    /// Rows, pixels.
    pub height: u32,
}

impl Roi {
    /// The whole `width × height` image.
    pub fn full(width: u32, height: u32) -> Roi {
        Roi {
            u0: 0,
            v0: 0,
            width,
            height,
        }
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether full-image pixel `(u, v)` lies inside.
    #[inline]
    pub fn contains(&self, u: u32, v: u32) -> bool {
        u >= self.u0 && v >= self.v0 && u - self.u0 < self.width && v - self.v0 < self.height
    }

    /// The pixels a sphere (camera coordinates, mm) can cover, plus one pixel of margin, cut to a
    /// `width × height` image; `None` when it covers none. A sphere reaching behind the camera
    /// gets the whole image.
    pub fn around_sphere(
        centre: &Point3<f32>,
        radius_mm: f32,
        intrinsics: &Intrinsics,
        width: u32,
        height: u32,
    ) -> Option<Roi> {
        let r = radius_mm.abs();
        if centre.z + r <= 0.0 || width == 0 || height == 0 {
            return None;
        }
        if centre.z - r <= 0.0 {
            return Some(Roi::full(width, height));
        }
        let (near, far) = (centre.z - r, centre.z + r);
        // Every point of the sphere has x in [cx - r, cx + r] and z in [near, far]: the extremes
        // of x / z are at those corners.
        let bound = |c: f32, sign: f32| {
            let n = c + sign * r;
            let (a, b) = (n / near, n / far);
            if sign > 0.0 {
                a.max(b)
            } else {
                a.min(b)
            }
        };
        let u_min = (intrinsics.cx + intrinsics.fx * bound(centre.x, -1.0)).floor() - 1.0;
        let u_max = (intrinsics.cx + intrinsics.fx * bound(centre.x, 1.0)).ceil() + 1.0;
        let v_min = (intrinsics.cy + intrinsics.fy * bound(centre.y, -1.0)).floor() - 1.0;
        let v_max = (intrinsics.cy + intrinsics.fy * bound(centre.y, 1.0)).ceil() + 1.0;
        let u0 = u_min.max(0.0);
        let v0 = v_min.max(0.0);
        let u1 = u_max.min(width as f32 - 1.0);
        let v1 = v_max.min(height as f32 - 1.0);
        if !(u0 <= u1 && v0 <= v1) {
            return None;
        }
        Some(Roi {
            u0: u0 as u32,
            v0: v0 as u32,
            width: (u1 - u0) as u32 + 1,
            height: (v1 - v0) as u32 + 1,
        })
    }
}

/// The centre of a mesh's bounding box and the radius of the sphere around it that holds every
/// vertex (model coordinates, mm): with [`Roi::around_sphere`], where a mesh can appear.
pub fn bounding_sphere(mesh: &Mesh) -> (Point3<f32>, f32) {
    let Some(first) = mesh.positions.first() else {
        return (Point3::origin(), 0.0);
    };
    let (mut lo, mut hi) = (*first, *first);
    for p in &mesh.positions {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let c = nalgebra::center(&lo, &hi);
    let r2 = mesh
        .positions
        .iter()
        .map(|p| (p - c).norm_squared())
        .fold(0.0f32, f32::max);
    (c, r2.sqrt())
}

/// A depth image of several objects with, per pixel, which object is seen.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRender {
    /// The depth of all the objects together.
    pub depth: DepthImage,
    /// Index into the rendered object list of the object seen at each pixel, [`NO_OBJECT`] for
    /// background; row-major like `depth`.
    pub object_index: Vec<u32>,
}

impl SceneRender {
    /// How many pixels show object `index`.
    pub fn object_pixels(&self, index: u32) -> usize {
        self.object_index.iter().filter(|&&i| i == index).count()
    }
}

/// Renders one mesh at `pose` (model → camera) into a new `width × height` depth image.
pub fn render_depth(
    mesh: &Mesh,
    pose: &Pose,
    intrinsics: &Intrinsics,
    width: u32,
    height: u32,
) -> Result<DepthImage> {
    let mut renderer = Renderer::new();
    renderer.render_into(mesh, pose, intrinsics, Roi::full(width, height))?;
    Ok(renderer.to_depth_image())
}

/// Renders several meshes, each at its pose, into one image; the object index of a pixel is the
/// position in `objects` of the mesh seen there.
pub fn render_scene(
    objects: &[(&Mesh, Pose)],
    intrinsics: &Intrinsics,
    width: u32,
    height: u32,
) -> Result<SceneRender> {
    let mut renderer = Renderer::new().track_objects(true);
    renderer.clear(Roi::full(width, height));
    for (i, (mesh, pose)) in objects.iter().enumerate() {
        renderer.draw(mesh, pose, intrinsics, i as u32)?;
    }
    Ok(SceneRender {
        depth: renderer.to_depth_image(),
        object_index: renderer.object_index.clone(),
    })
}

/// A reusable z-buffer over a region of interest. Configure with the builder methods, then
/// [`clear`](Renderer::clear) and [`draw`](Renderer::draw) (or [`render_into`](Renderer::render_into)).
#[derive(Clone, Debug)]
pub struct Renderer {
    roi: Roi,
    depth_mm: Vec<f32>,
    object_index: Vec<u32>,
    near_mm: f32,
    cull_back_faces: bool,
    track_objects: bool,
    camera_points: Vec<Point3<f32>>,
    screen: Vec<[i32; 2]>,
}

impl Default for Renderer {
    fn default() -> Self {
        Renderer::new()
    }
}

impl Renderer {
    /// A renderer with near plane [`DEFAULT_NEAR_MM`], back-face culling on and no object index.
    pub fn new() -> Renderer {
        Renderer {
            roi: Roi::default(),
            depth_mm: Vec::new(),
            object_index: Vec::new(),
            near_mm: DEFAULT_NEAR_MM,
            cull_back_faces: true,
            track_objects: false,
            camera_points: Vec::new(),
            screen: Vec::new(),
        }
    }

    /// Surfaces closer than `near_mm` (> 0) are cut away. Default [`DEFAULT_NEAR_MM`].
    pub fn near_mm(mut self, near_mm: f32) -> Renderer {
        self.near_mm = if near_mm.is_finite() && near_mm > 0.0 {
            near_mm
        } else {
            DEFAULT_NEAR_MM
        };
        self
    }

    /// Skip triangles facing away from the camera. Default on: it halves the work and is exact for
    /// closed meshes wound counter-clockwise seen from outside; turn it off for open surfaces.
    pub fn cull_back_faces(mut self, cull: bool) -> Renderer {
        self.cull_back_faces = cull;
        self
    }

    /// Keep a per-pixel object index (see [`Renderer::object_index`]). Default off: one buffer
    /// less to clear and write.
    pub fn track_objects(mut self, track: bool) -> Renderer {
        self.track_objects = track;
        self
    }

    /// Starts a new image over `roi`: every pixel becomes background.
    pub fn clear(&mut self, roi: Roi) {
        self.roi = roi;
        self.depth_mm.clear();
        self.depth_mm.resize(roi.area(), 0.0);
        self.object_index.clear();
        if self.track_objects {
            self.object_index.resize(roi.area(), NO_OBJECT);
        }
    }

    /// Clears to `roi` and draws one mesh (object index 0).
    pub fn render_into(
        &mut self,
        mesh: &Mesh,
        pose: &Pose,
        intrinsics: &Intrinsics,
        roi: Roi,
    ) -> Result<()> {
        self.clear(roi);
        self.draw(mesh, pose, intrinsics, 0)
    }

    /// The current region of interest.
    pub fn roi(&self) -> Roi {
        self.roi
    }

    /// Depth over the region of interest, row-major (`roi.width` per row), 0.0 = background.
    pub fn depth_mm(&self) -> &[f32] {
        &self.depth_mm
    }

    /// Object index over the region of interest (empty unless tracking is on).
    pub fn object_index(&self) -> &[u32] {
        &self.object_index
    }

    /// Depth at full-image pixel `(u, v)`, `None` for background or outside the region.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> Option<f32> {
        if !self.roi.contains(u, v) {
            return None;
        }
        let d = self.depth_mm[((v - self.roi.v0) * self.roi.width + (u - self.roi.u0)) as usize];
        (d > 0.0).then_some(d)
    }

    /// A copy of the region's depth as an image of the region's size.
    pub fn to_depth_image(&self) -> DepthImage {
        DepthImage {
            width: self.roi.width,
            height: self.roi.height,
            depth_mm: self.depth_mm.clone(),
        }
    }

    /// Draws `mesh` at `pose` (model → camera) into the current image, keeping for each pixel the
    /// nearest surface; pixels it wins get `object_index` when tracking is on.
    pub fn draw(
        &mut self,
        mesh: &Mesh,
        pose: &Pose,
        intrinsics: &Intrinsics,
        object_index: u32,
    ) -> Result<()> {
        intrinsics.validate()?;
        let n = mesh.positions.len();
        if let Some(bad) = mesh.faces.iter().flatten().find(|&&i| i as usize >= n) {
            return Err(Error::InvalidMesh(format!(
                "face refers to vertex {bad}, but the mesh has {n} vertices"
            )));
        }
        let (far_u, far_v) = (
            self.roi.u0 as u64 + self.roi.width as u64,
            self.roi.v0 as u64 + self.roi.height as u64,
        );
        if far_u > MAX_IMAGE_PX || far_v > MAX_IMAGE_PX {
            return Err(Error::InvalidParameter(format!(
                "region of interest {:?} reaches beyond {MAX_IMAGE_PX} pixels",
                self.roi
            )));
        }
        if self.roi.area() == 0 || mesh.faces.is_empty() {
            return Ok(());
        }
        let roi = self.roi;
        let window = Window {
            left: roi.u0 as f32 - GUARD_PX,
            right: roi.u0 as f32 + roi.width as f32 + GUARD_PX,
            top: roi.v0 as f32 - GUARD_PX,
            bottom: roi.v0 as f32 + roi.height as f32 + GUARD_PX,
        };
        let rotation: Matrix3<f32> = *pose.rotation.to_rotation_matrix().matrix();
        let translation = pose.translation.vector;
        self.camera_points.clear();
        self.screen.clear();
        let positions = &mesh.positions[..];
        let mut i = 0;
        #[cfg(target_arch = "x86_64")]
        while i + 4 <= positions.len() {
            // Four vertices at a time, each as the loop below moves and snaps it alone.
            // SAFETY: SSE2 is part of x86-64; the stores write arrays of four.
            unsafe {
                use crate::geometry::four::{lanes_of, moved};
                use std::arch::x86_64::*;
                let q = moved(
                    &rotation,
                    Some(&translation),
                    lanes_of(|j| positions[i + j].coords),
                );
                let [mut x, mut y, mut z] = [[0f32; 4]; 3];
                _mm_storeu_ps(x.as_mut_ptr(), q[0]);
                _mm_storeu_ps(y.as_mut_ptr(), q[1]);
                _mm_storeu_ps(z.as_mut_ptr(), q[2]);
                let screen = window.snap_four(q, intrinsics, self.near_mm);
                for j in 0..4 {
                    self.camera_points.push(Point3::new(x[j], y[j], z[j]));
                    self.screen.push(screen[j]);
                }
            }
            i += 4;
        }
        for p in &positions[i..] {
            let q = Point3::from(rotation * p.coords + translation);
            self.camera_points.push(q);
            self.screen.push(window.snap(&q, intrinsics, self.near_mm));
        }

        let Renderer {
            depth_mm,
            object_index: index_buffer,
            camera_points,
            screen,
            near_mm,
            cull_back_faces,
            track_objects,
            ..
        } = self;
        let (near_mm, cull) = (*near_mm, *cull_back_faces);
        let mut ctx = FaceContext::new(roi, intrinsics, near_mm, &window);
        if *track_objects {
            let mut shade = |i: usize, inv_z: f32| {
                let cur = depth_mm[i];
                if cur == 0.0 || inv_z * cur > 1.0 {
                    depth_mm[i] = 1.0 / inv_z;
                    index_buffer[i] = object_index;
                }
            };
            for face in &mesh.faces {
                ctx.face(face, camera_points, screen, cull, &mut shade);
            }
        } else {
            let mut shade = |i: usize, inv_z: f32| {
                let cur = depth_mm[i];
                if cur == 0.0 || inv_z * cur > 1.0 {
                    depth_mm[i] = 1.0 / inv_z;
                }
            };
            for face in &mesh.faces {
                ctx.face(face, camera_points, screen, cull, &mut shade);
            }
        }
        Ok(())
    }
}

/// Pixel coordinate to 1/256-pixel fixed point, rounding half away from zero (a plain cast after
/// the offset: `f32::round` is a library call on baseline x86-64).
#[inline]
fn to_fixed(x: f32) -> i64 {
    let s = x * SUBPIXEL;
    (s + 0.5f32.copysign(s)) as i64
}

/// The guard band in pixels: vertices inside it take the fast path.
struct Window {
    left: f32,
    right: f32,
    top: f32,
    bottom: f32,
}

impl Window {
    #[inline]
    fn snap(&self, q: &Point3<f32>, k: &Intrinsics, near_mm: f32) -> [i32; 2] {
        if !(q.z >= near_mm && q.z < f32::INFINITY) {
            return [OFF_SCREEN, 0];
        }
        let inv = 1.0 / q.z;
        let x = k.fx * q.x * inv + k.cx;
        let y = k.fy * q.y * inv + k.cy;
        if x >= self.left && x <= self.right && y >= self.top && y <= self.bottom {
            [to_fixed(x) as i32, to_fixed(y) as i32]
        } else {
            [OFF_SCREEN, 0]
        }
    }

    /// [`Window::snap`] of four camera points given by their coordinates' lanes, with the same
    /// operations in the same order.
    ///
    /// # Safety
    ///
    /// SSE2 must be available, as it always is on x86-64.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn snap_four(
        &self,
        [qx, qy, qz]: [std::arch::x86_64::__m128; 3],
        k: &Intrinsics,
        near_mm: f32,
    ) -> [[i32; 2]; 4] {
        use crate::geometry::four::rounded;
        use std::arch::x86_64::*;
        let s = _mm_set1_ps;
        let valid = _mm_and_ps(
            _mm_cmpge_ps(qz, s(near_mm)),
            _mm_cmplt_ps(qz, s(f32::INFINITY)),
        );
        let inv = _mm_div_ps(s(1.0), qz);
        let x = _mm_add_ps(_mm_mul_ps(_mm_mul_ps(s(k.fx), qx), inv), s(k.cx));
        let y = _mm_add_ps(_mm_mul_ps(_mm_mul_ps(s(k.fy), qy), inv), s(k.cy));
        let inside = _mm_and_ps(
            _mm_and_ps(
                _mm_cmpge_ps(x, s(self.left)),
                _mm_cmple_ps(x, s(self.right)),
            ),
            _mm_and_ps(
                _mm_cmpge_ps(y, s(self.top)),
                _mm_cmple_ps(y, s(self.bottom)),
            ),
        );
        let mask = _mm_movemask_ps(_mm_and_ps(valid, inside));
        let [mut u, mut v] = [[0i32; 4]; 2];
        _mm_storeu_si128(
            u.as_mut_ptr() as *mut __m128i,
            rounded(_mm_mul_ps(x, s(SUBPIXEL))),
        );
        _mm_storeu_si128(
            v.as_mut_ptr() as *mut __m128i,
            rounded(_mm_mul_ps(y, s(SUBPIXEL))),
        );
        std::array::from_fn(|j| {
            if mask >> j & 1 == 1 {
                [u[j], v[j]]
            } else {
                [OFF_SCREEN, 0]
            }
        })
    }

    /// The clipping planes, as `n · p ≥ 0` in camera space (the near plane is handled apart).
    fn planes(&self, k: &Intrinsics) -> [Vector3<f32>; 4] {
        [
            Vector3::new(k.fx, 0.0, k.cx - self.left),
            Vector3::new(-k.fx, 0.0, self.right - k.cx),
            Vector3::new(0.0, k.fy, k.cy - self.top),
            Vector3::new(0.0, -k.fy, self.bottom - k.cy),
        ]
    }
}

/// Camera-space 1/z of a triangle's plane as an affine function of pixel coordinates, clamped to
/// the triangle's own depth range.
#[derive(Clone, Copy)]
struct DepthPlane {
    a: f32,
    b: f32,
    c: f32,
    inv_min: f32,
    inv_max: f32,
}

impl DepthPlane {
    fn new(p: &[Point3<f32>; 3], camera: &Camera) -> DepthPlane {
        let z_min = p[0].z.min(p[1].z).min(p[2].z);
        let z_max = p[0].z.max(p[1].z).max(p[2].z);
        let inv_zz = 1.0 / (z_min * z_max).max(f32::MIN_POSITIVE);
        let (inv_min, inv_max) = (z_min * inv_zz, z_max * inv_zz);
        // Ray r(u, v) = ((u - cx)/fx, (v - cy)/fy, 1) meets n·x = d at z = d / (n·r).
        let normal = (p[1] - p[0]).cross(&(p[2] - p[0]));
        let inv_d = 1.0 / normal.dot(&p[0].coords);
        let (nx, ny) = (normal.x * camera.inv_fx, normal.y * camera.inv_fy);
        let a = nx * inv_d;
        let b = ny * inv_d;
        let c = (normal.z - nx * camera.cx - ny * camera.cy) * inv_d;
        if a.is_finite() && b.is_finite() && c.is_finite() {
            DepthPlane {
                a,
                b,
                c,
                inv_min,
                inv_max,
            }
        } else {
            // Seen exactly edge-on: any depth in the triangle's range will do.
            DepthPlane {
                a: 0.0,
                b: 0.0,
                c: 2.0 / (z_min + z_max),
                inv_min,
                inv_max,
            }
        }
    }

    #[inline]
    fn inv_z(&self, u: i64, v: i64) -> f32 {
        (self.a * u as f32 + self.b * v as f32 + self.c)
            .max(self.inv_min)
            .min(self.inv_max)
    }
}

/// The intrinsics as the depth planes use them.
struct Camera {
    inv_fx: f32,
    inv_fy: f32,
    cx: f32,
    cy: f32,
}

struct FaceContext<'a> {
    roi: Roi,
    camera: Camera,
    intrinsics: &'a Intrinsics,
    near_mm: f32,
    window: &'a Window,
}

impl<'a> FaceContext<'a> {
    fn new(roi: Roi, intrinsics: &'a Intrinsics, near_mm: f32, window: &'a Window) -> Self {
        let camera = Camera {
            inv_fx: 1.0 / intrinsics.fx,
            inv_fy: 1.0 / intrinsics.fy,
            cx: intrinsics.cx,
            cy: intrinsics.cy,
        };
        FaceContext {
            roi,
            camera,
            intrinsics,
            near_mm,
            window,
        }
    }

    #[inline]
    fn face(
        &mut self,
        face: &[u32; 3],
        camera_points: &[Point3<f32>],
        screen: &[[i32; 2]],
        cull: bool,
        shade: &mut impl FnMut(usize, f32),
    ) {
        let [i0, i1, i2] = face.map(|i| i as usize);
        let s = [screen[i0], screen[i1], screen[i2]];
        let points = || [camera_points[i0], camera_points[i1], camera_points[i2]];
        if s.iter().all(|v| v[0] != OFF_SCREEN) {
            let v = s.map(|[x, y]| [x as i64, y as i64]);
            let camera = &self.camera;
            raster_triangle(
                v,
                cull,
                || DepthPlane::new(&points(), camera),
                &self.roi,
                shade,
            );
        } else {
            let p = points();
            let finite = p.iter().all(|q| q.coords.iter().all(|c| c.is_finite()));
            if !finite || p.iter().all(|q| q.z < self.near_mm) {
                return;
            }
            // Front faces (counter-clockwise seen from outside) have their normal toward the camera.
            let normal = (p[1] - p[0]).cross(&(p[2] - p[0]));
            if cull && normal.dot(&p[0].coords) >= 0.0 {
                return;
            }
            let plane = DepthPlane::new(&p, &self.camera);
            self.clipped(&p, &plane, shade);
        }
    }

    /// Clips a triangle against the near plane and the guard band, then draws the pieces.
    fn clipped(
        &mut self,
        p: &[Point3<f32>; 3],
        plane: &DepthPlane,
        shade: &mut impl FnMut(usize, f32),
    ) {
        let mut poly = [Point3::origin(); 9];
        let mut scratch = [Point3::origin(); 9];
        poly[..3].copy_from_slice(p);
        let mut n = 3;
        let near = self.near_mm;
        n = clip_polygon(&poly, n, &mut scratch, |q| q.z - near);
        std::mem::swap(&mut poly, &mut scratch);
        for normal in self.window.planes(self.intrinsics) {
            if n < 3 {
                return;
            }
            n = clip_polygon(&poly, n, &mut scratch, |q| normal.dot(&q.coords));
            std::mem::swap(&mut poly, &mut scratch);
        }
        if n < 3 {
            return;
        }
        let k = self.intrinsics;
        let mut snapped = [[0i64; 2]; 9];
        for (dst, q) in snapped.iter_mut().zip(&poly[..n]) {
            let z = q.z.max(near);
            let x = k.fx * q.x / z + k.cx;
            let y = k.fy * q.y / z + k.cy;
            *dst = [to_fixed(x), to_fixed(y)];
        }
        for i in 1..n - 1 {
            raster_triangle(
                [snapped[0], snapped[i], snapped[i + 1]],
                false,
                || *plane,
                &self.roi,
                shade,
            );
        }
    }
}

/// One Sutherland–Hodgman step: keeps the part of polygon `src[..n]` where `dist ≥ 0`. Edge
/// crossings are computed from the lexicographically smaller endpoint so that a shared edge is cut
/// at the same point in both of its triangles.
fn clip_polygon(
    src: &[Point3<f32>; 9],
    n: usize,
    dst: &mut [Point3<f32>; 9],
    dist: impl Fn(&Point3<f32>) -> f32,
) -> usize {
    let mut m = 0;
    for i in 0..n {
        let (a, b) = (src[i], src[(i + 1) % n]);
        let (da, db) = (dist(&a), dist(&b));
        if da >= 0.0 && m < 9 {
            dst[m] = a;
            m += 1;
        }
        if (da >= 0.0) != (db >= 0.0) && m < 9 {
            let (from, to, df, dt) = if (a.x, a.y, a.z) < (b.x, b.y, b.z) {
                (a, b, da, db)
            } else {
                (b, a, db, da)
            };
            let t = df / (df - dt);
            dst[m] = from + (to - from) * t;
            m += 1;
        }
    }
    m
}

/// Scans a triangle given in 1/256-pixel fixed point over its bounding box (cut to the region of
/// interest), calling `shade(buffer index, 1/z)` for every covered pixel centre. Top-left rule:
/// a centre exactly on an edge belongs to the triangle whose edge is a top or a left edge.
#[inline]
fn raster_triangle(
    mut v: [[i64; 2]; 3],
    cull_back_faces: bool,
    make_plane: impl Fn() -> DepthPlane,
    roi: &Roi,
    shade: &mut impl FnMut(usize, f32),
) {
    let orient = |a: [i64; 2], b: [i64; 2], p: [i64; 2]| {
        (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
    };
    // With y pointing down, a triangle wound counter-clockwise seen from the camera (a front
    // face) has negative area here.
    let area = orient(v[0], v[1], v[2]);
    let min_x = v[0][0].min(v[1][0]).min(v[2][0]);
    let max_x = v[0][0].max(v[1][0]).max(v[2][0]);
    let min_y = v[0][1].min(v[1][1]).min(v[2][1]);
    let max_y = v[0][1].max(v[1][1]).max(v[2][1]);
    let u_start = ((min_x + SUBPIXEL_I - 1) >> SUBPIXEL_BITS).max(roi.u0 as i64);
    let u_end = (max_x >> SUBPIXEL_BITS).min(roi.u0 as i64 + roi.width as i64 - 1);
    let v_start = ((min_y + SUBPIXEL_I - 1) >> SUBPIXEL_BITS).max(roi.v0 as i64);
    let v_end = (max_y >> SUBPIXEL_BITS).min(roi.v0 as i64 + roi.height as i64 - 1);
    // One branch for all the reasons to draw nothing (most triangles of a dense mesh are culled
    // or cover no pixel centre, and these tests are unpredictable).
    let culled = (area == 0) | (cull_back_faces & (area > 0));
    if culled | (u_start > u_end) | (v_start > v_end) {
        return;
    }
    if area < 0 {
        v.swap(1, 2);
    }
    let origin = [u_start * SUBPIXEL_I, v_start * SUBPIXEL_I];
    let mut row = [0i64; 3];
    let mut step_u = [0i64; 3];
    let mut step_v = [0i64; 3];
    for (k, (a, b)) in [(v[1], v[2]), (v[2], v[0]), (v[0], v[1])]
        .into_iter()
        .enumerate()
    {
        let top_left = (a[1] == b[1] && b[0] > a[0]) || b[1] < a[1];
        row[k] = orient(a, b, origin) - if top_left { 0 } else { 1 };
        step_u[k] = -(b[1] - a[1]) * SUBPIXEL_I;
        step_v[k] = (b[0] - a[0]) * SUBPIXEL_I;
    }
    let width = roi.width as usize;
    // Most triangles of a dense mesh cover no pixel centre at all: the depth plane is set up on
    // the first pixel covered.
    let mut plane: Option<DepthPlane> = None;
    // Narrow boxes are cheapest tested pixel by pixel; wide ones find each row's span exactly
    // (a floating-point estimate settled with the integer edge functions).
    let narrow = u_end - u_start < 12;
    let inv_step = if narrow {
        [0.0; 3]
    } else {
        step_u.map(|st| {
            if st == 0 {
                0.0
            } else {
                1.0 / (st as f64).abs()
            }
        })
    };
    for y in v_start..=v_end {
        let base = (y - roi.v0 as i64) as usize * width + (u_start - roi.u0 as i64) as usize;
        if narrow {
            let [mut w0, mut w1, mut w2] = row;
            for dx in 0..=u_end - u_start {
                if (w0 | w1 | w2) >= 0 {
                    let pl = plane.get_or_insert_with(&make_plane);
                    shade(base + dx as usize, pl.inv_z(u_start + dx, y));
                }
                w0 += step_u[0];
                w1 += step_u[1];
                w2 += step_u[2];
            }
        } else {
            let (lo, hi) = row_span(&row, &step_u, &inv_step, u_end - u_start);
            for dx in lo..=hi {
                let pl = plane.get_or_insert_with(&make_plane);
                shade(base + dx as usize, pl.inv_z(u_start + dx, y));
            }
        }
        row[0] += step_v[0];
        row[1] += step_v[1];
        row[2] += step_v[2];
    }
}

/// The offsets `lo..=hi` (from the box's left column, at most `last`) where all three edge
/// functions of a row are non-negative; empty when `lo > hi`.
#[inline]
fn row_span(row: &[i64; 3], step_u: &[i64; 3], inv_step: &[f64; 3], last: i64) -> (i64, i64) {
    let (mut lo, mut hi) = (0i64, last);
    for k in 0..3 {
        let (w, step) = (row[k], step_u[k]);
        let covered = |dx: i64| w + step * dx >= 0;
        if step > 0 {
            if w < 0 {
                let mut first = ((-w) as f64 * inv_step[k]).ceil() as i64;
                while !covered(first) {
                    first += 1;
                }
                while first > 0 && covered(first - 1) {
                    first -= 1;
                }
                lo = lo.max(first);
            }
        } else if step < 0 {
            if w < 0 {
                return (1, 0);
            }
            let mut end = (w as f64 * inv_step[k]) as i64;
            while covered(end + 1) {
                end += 1;
            }
            while end >= 0 && !covered(end) {
                end -= 1;
            }
            hi = hi.min(end);
        } else if w < 0 {
            return (1, 0);
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::parts::{box_mesh, cylinder_mesh, Part};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2};

    const K: Intrinsics = Intrinsics::LMO;

    /// Four camera points snapped side by side land where each snapped alone does, or off
    /// screen with it: in the window, beyond its edges, behind the near plane, at infinity.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_snapped_points_are_each_snapped_alone() {
        let window = Window {
            left: 100.0 - GUARD_PX,
            right: 300.0 + GUARD_PX,
            top: 50.0 - GUARD_PX,
            bottom: 250.0 + GUARD_PX,
        };
        let mut rng = crate::geometry::rng::Rng::new(6);
        let mut r = || rng.uniform() as f32;
        let mut on_screen = 0;
        for n in 0..2000 {
            let q: [Point3<f32>; 4] = std::array::from_fn(|_| {
                let z = match n % 5 {
                    0 => 5.0 * r(),
                    1 => f32::INFINITY,
                    _ => 100.0 + 1500.0 * r(),
                };
                Point3::new(800.0 * (r() - 0.5), 800.0 * (r() - 0.5), z)
            });
            // SAFETY: SSE2 is part of x86-64.
            let four = unsafe {
                window.snap_four(crate::geometry::four::lanes_of(|j| q[j].coords), &K, 10.0)
            };
            for (j, q) in q.iter().enumerate() {
                let alone = window.snap(q, &K, 10.0);
                assert_eq!(four[j], alone, "{q:?}");
                on_screen += usize::from(alone[0] != OFF_SCREEN);
            }
        }
        assert!(
            on_screen > 1000 && on_screen < 7000,
            "{on_screen} on screen"
        );
    }

    fn ray(u: u32, v: u32) -> Vector3<f32> {
        Vector3::new((u as f32 - K.cx) / K.fx, (v as f32 - K.cy) / K.fy, 1.0)
    }

    /// A flat grid of `n × n` cells in the plane z = 0 of its own frame, facing -z (toward a camera
    /// looking along +z), vertices jittered to make edges at every angle.
    fn jittered_grid(size_mm: f32, n: usize, jitter: f32) -> Mesh {
        let mut mesh = Mesh::default();
        let mut state = 0x9e37_79b9_u32;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32 - 0.5
        };
        let cell = size_mm / n as f32;
        for j in 0..=n {
            for i in 0..=n {
                let border = i == 0 || j == 0 || i == n || j == n;
                let (dx, dy) = if border {
                    (0.0, 0.0)
                } else {
                    (rnd() * jitter * cell, rnd() * jitter * cell)
                };
                mesh.positions.push(Point3::new(
                    i as f32 * cell - size_mm / 2.0 + dx,
                    j as f32 * cell - size_mm / 2.0 + dy,
                    0.0,
                ));
                mesh.normals.push(-Vector3::z());
            }
        }
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                // Counter-clockwise seen from -z (the camera side).
                mesh.faces.push([at(i, j), at(i, j + 1), at(i + 1, j)]);
                mesh.faces
                    .push([at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)]);
            }
        }
        mesh
    }

    #[test]
    fn fronto_parallel_plane_renders_its_distance() {
        let plane = jittered_grid(4000.0, 8, 0.0);
        let pose = Isometry3::translation(0.0, 0.0, 800.0);
        let image = render_depth(&plane, &pose, &K, 640, 480).unwrap();
        assert_eq!(image.foreground_count(), 640 * 480);
        for &d in &image.depth_mm {
            assert!((d - 800.0).abs() < 1e-3, "depth {d}");
        }
    }

    #[test]
    fn tilted_plane_matches_ray_intersection() {
        let plane = jittered_grid(3000.0, 20, 0.6);
        let rotation = UnitQuaternion::from_euler_angles(0.5, -0.4, 0.3);
        let pose = Isometry3::from_parts(Translation3::new(30.0, -20.0, 1200.0), rotation);
        let image = render_depth(&plane, &pose, &K, 640, 480).unwrap();
        let normal = rotation * Vector3::z();
        let d = normal.dot(&pose.translation.vector);
        let mut checked = 0;
        for v in (0..480).step_by(7) {
            for u in (0..640).step_by(7) {
                let expected = d / normal.dot(&ray(u, v));
                if let Some(z) = image.get(u, v) {
                    assert!(
                        ((z - expected) / expected).abs() < 1e-5,
                        "({u},{v}): {z} vs {expected}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 5000, "only {checked} pixels covered");
    }

    /// Ray–box intersection (slabs) in the box's frame; the box is centred with half-sizes `h`.
    fn ray_box(pose: &Pose, h: Vector3<f32>, dir_cam: Vector3<f32>) -> Option<f32> {
        let inv = pose.inverse();
        let o = inv * Point3::origin();
        let d = inv.rotation * dir_cam;
        let (mut t0, mut t1) = (f32::MIN, f32::MAX);
        for k in 0..3 {
            let (a, b) = ((-h[k] - o[k]) / d[k], (h[k] - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t0 <= t1 && t0 > 0.0).then_some(t0)
    }

    #[test]
    fn cube_matches_analytic_depth() {
        let h = Vector3::new(60.0, 45.0, 80.0);
        let cube = box_mesh(h * 2.0);
        let pose = Isometry3::from_parts(
            Translation3::new(25.0, -15.0, 650.0),
            UnitQuaternion::from_euler_angles(0.6, 0.9, -0.2),
        );
        for cull in [true, false] {
            let mut r = Renderer::new().cull_back_faces(cull);
            r.render_into(&cube, &pose, &K, Roi::full(640, 480))
                .unwrap();
            let (mut inside, mut edge_disagreements) = (0, 0);
            for v in 0..480 {
                for u in 0..640 {
                    let expected = ray_box(&pose, h, ray(u, v));
                    match (r.get(u, v), expected) {
                        (Some(z), Some(t)) => {
                            // t is along a ray with unit z component: it is the depth.
                            assert!(
                                ((z - t) / t).abs() < 1e-5,
                                "({u},{v}) cull={cull}: {z} vs {t}"
                            );
                            inside += 1;
                        }
                        (None, None) => {}
                        _ => {
                            // Coverage may only differ within a hair of the silhouette.
                            let near_edge = [(0.01, 0.0), (-0.01, 0.0), (0.0, 0.01), (0.0, -0.01)]
                                .iter()
                                .any(|&(du, dv)| {
                                    let r2 = Vector3::new(
                                        (u as f32 + du - K.cx) / K.fx,
                                        (v as f32 + dv - K.cy) / K.fy,
                                        1.0,
                                    );
                                    ray_box(&pose, h, r2).is_some() != expected.is_some()
                                });
                            assert!(
                                near_edge,
                                "({u},{v}) cull={cull}: coverage differs away from the silhouette"
                            );
                            edge_disagreements += 1;
                        }
                    }
                }
            }
            assert!(inside > 10_000, "cube covers only {inside} pixels");
            assert!(
                edge_disagreements < 10,
                "{edge_disagreements} silhouette pixels disagree"
            );
        }
    }

    #[test]
    fn shared_edges_cover_every_pixel_once() {
        let grid = jittered_grid(600.0, 40, 0.3);
        let pose = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 700.0),
            UnitQuaternion::from_euler_angles(0.2, -0.1, 0.4),
        );
        let mut count = vec![0u8; 640 * 480];
        let window = Window {
            left: -GUARD_PX,
            right: 640.0 + GUARD_PX,
            top: -GUARD_PX,
            bottom: 480.0 + GUARD_PX,
        };
        let points: Vec<Point3<f32>> = grid.positions.iter().map(|p| pose * p).collect();
        let screen: Vec<[i32; 2]> = points.iter().map(|q| window.snap(q, &K, 1.0)).collect();
        let mut ctx = FaceContext::new(Roi::full(640, 480), &K, 1.0, &window);
        let mut shade = |i: usize, _| count[i] += 1;
        for f in &grid.faces {
            ctx.face(f, &points, &screen, true, &mut shade);
        }
        // The grid's outline in the image, shrunk by a pixel: every centre inside is hit once.
        let corner = |x: f32, y: f32| K.project(&(pose * Point3::new(x, y, 0.0)));
        let quad = [
            corner(-300.0, -300.0),
            corner(300.0, -300.0),
            corner(300.0, 300.0),
            corner(-300.0, 300.0),
        ];
        let inside = |p: Vector2<f32>| {
            (0..4).all(|k| {
                let (a, b) = (quad[k], quad[(k + 1) % 4]);
                let e = b - a;
                let cross = e.x * (p.y - a.y) - e.y * (p.x - a.x);
                cross / e.norm() > 1.5
            }) || (0..4).all(|k| {
                let (a, b) = (quad[k], quad[(k + 1) % 4]);
                let e = b - a;
                let cross = e.x * (p.y - a.y) - e.y * (p.x - a.x);
                cross / e.norm() < -1.5
            })
        };
        let mut checked = 0;
        for v in 0..480 {
            for u in 0..640 {
                let c = count[(v * 640 + u) as usize];
                assert!(c <= 1, "({u},{v}) drawn {c} times");
                if inside(Vector2::new(u as f32, v as f32)) {
                    assert_eq!(c, 1, "gap at ({u},{v})");
                    checked += 1;
                }
            }
        }
        assert!(checked > 50_000, "only {checked} pixels checked");
    }

    #[test]
    fn closed_meshes_have_no_holes_in_their_silhouette() {
        let meshes = [
            cylinder_mesh(60.0, 150.0, 64),
            Part::ToothedDisc.mesh(),
            Part::TPipe.mesh(),
        ];
        for (m, mesh) in meshes.iter().enumerate() {
            for (s, rotation) in [(0.3, 0.2, 0.1), (1.2, -0.7, 2.0), (0.0, 1.5707964, 0.0)]
                .into_iter()
                .enumerate()
            {
                let pose = Isometry3::from_parts(
                    Translation3::new(-10.0, 5.0, 600.0),
                    UnitQuaternion::from_euler_angles(rotation.0, rotation.1, rotation.2),
                );
                let image = render_depth(mesh, &pose, &K, 640, 480).unwrap();
                // A fill-rule gap shows as background pixels enclosed by foreground on all four
                // sides (the parts' real through-holes are several pixels wide).
                let mut holes = 0;
                for v in 1..479 {
                    for u in 1..639 {
                        if image.get(u, v).is_none()
                            && [(u - 1, v), (u + 1, v), (u, v - 1), (u, v + 1)]
                                .iter()
                                .all(|&(a, b)| image.get(a, b).is_some())
                        {
                            holes += 1;
                        }
                    }
                }
                assert_eq!(holes, 0, "mesh {m} pose {s}: {holes} isolated holes");
                let area = image.foreground_count();
                assert!(area > 2000, "mesh {m} pose {s}: only {area} pixels");
            }
        }
    }

    #[test]
    fn nearer_object_occludes() {
        let cube = box_mesh(Vector3::new(100.0, 100.0, 100.0));
        let front = Isometry3::translation(0.0, 0.0, 500.0);
        let back = Isometry3::translation(30.0, 0.0, 700.0);
        for order in [
            [(&cube, back), (&cube, front)],
            [(&cube, front), (&cube, back)],
        ] {
            let scene = render_scene(&order, &K, 640, 480).unwrap();
            let front_index = if order[0].1 == front { 0 } else { 1 };
            let (u, v) = (K.cx.round() as u32, K.cy.round() as u32);
            assert_eq!(scene.object_index[(v * 640 + u) as usize], front_index);
            assert!((scene.depth.get(u, v).unwrap() - 450.0).abs() < 1e-3);
            let alone = render_depth(&cube, &back, &K, 640, 480)
                .unwrap()
                .foreground_count();
            let visible_back = scene.object_pixels(1 - front_index);
            assert!(
                visible_back > 0 && visible_back < alone / 2,
                "back cube shows {visible_back} of {alone} pixels"
            );
        }
    }

    #[test]
    fn behind_the_camera_renders_nothing() {
        let mesh = Part::FlangedCylinder.mesh();
        for cull in [true, false] {
            let mut r = Renderer::new().cull_back_faces(cull);
            r.render_into(
                &mesh,
                &Isometry3::translation(0.0, 0.0, -500.0),
                &K,
                Roi::full(640, 480),
            )
            .unwrap();
            assert!(r.depth_mm().iter().all(|&d| d == 0.0));
        }
    }

    #[test]
    fn plane_through_the_camera_is_cut_at_the_near_plane() {
        // A floor 100 mm below the camera, stretching from behind it to far ahead.
        let floor = jittered_grid(20_000.0, 10, 0.0);
        let rotation = UnitQuaternion::from_euler_angles(std::f32::consts::FRAC_PI_2, 0.0, 0.0);
        let pose = Isometry3::from_parts(Translation3::new(0.0, 100.0, 0.0), rotation);
        let normal = rotation * Vector3::z();
        let mut image = Renderer::new().cull_back_faces(false);
        image
            .render_into(&floor, &pose, &K, Roi::full(640, 480))
            .unwrap();
        let d = normal.dot(&pose.translation.vector);
        let mut covered = 0;
        for v in 0..480 {
            for u in 0..640 {
                let t = d / normal.dot(&ray(u, v));
                match image.get(u, v) {
                    Some(z) => {
                        assert!(((z - t) / t).abs() < 1e-4, "({u},{v}): {z} vs {t}");
                        covered += 1;
                    }
                    None => assert!(t <= 0.0 || t > 9_000.0, "({u},{v}) missing, expected {t}"),
                }
            }
        }
        assert!(covered > 100_000, "{covered}");
    }

    #[test]
    fn roi_equals_window_of_full_render() {
        let mesh = Part::LBracket.mesh();
        let pose = Isometry3::from_parts(
            Translation3::new(40.0, 20.0, 900.0),
            UnitQuaternion::from_euler_angles(0.4, 0.8, 0.2),
        );
        let full = render_depth(&mesh, &pose, &K, 640, 480).unwrap();
        let (c, r) = bounding_sphere(&mesh);
        let roi = Roi::around_sphere(&(pose * c), r, &K, 640, 480).unwrap();
        assert!(roi.width < 640 && roi.height < 480, "{roi:?}");
        let mut renderer = Renderer::new();
        renderer.render_into(&mesh, &pose, &K, roi).unwrap();
        for v in 0..480 {
            for u in 0..640 {
                if roi.contains(u, v) {
                    assert_eq!(renderer.get(u, v), full.get(u, v), "({u},{v})");
                } else {
                    assert_eq!(full.get(u, v), None, "({u},{v}) outside the sphere's box");
                }
            }
        }
        // A region off the object sees nothing; the buffer is reused without reallocation.
        renderer
            .render_into(
                &mesh,
                &pose,
                &K,
                Roi {
                    u0: 0,
                    v0: 0,
                    width: 16,
                    height: 16,
                },
            )
            .unwrap();
        assert!(renderer.depth_mm().iter().all(|&d| d == 0.0));
    }

    #[test]
    fn refuses_bad_input() {
        let mut mesh = box_mesh(Vector3::new(1.0, 1.0, 1.0));
        mesh.faces.push([0, 1, 99]);
        let pose = Isometry3::translation(0.0, 0.0, 100.0);
        assert!(matches!(
            render_depth(&mesh, &pose, &K, 64, 48),
            Err(Error::InvalidMesh(_))
        ));
        let bad = Intrinsics { fx: 0.0, ..K };
        assert!(render_depth(&box_mesh(Vector3::new(1.0, 1.0, 1.0)), &pose, &bad, 64, 48).is_err());
        // Non-finite vertices draw nothing where they are, and never panic.
        let mut odd = Part::TPipe.mesh();
        for (k, p) in odd.positions.iter_mut().enumerate() {
            match k % 7 {
                0 => p.x = f32::NAN,
                3 => p.z = f32::INFINITY,
                5 => p.y = f32::NEG_INFINITY,
                _ => {}
            }
        }
        for cull in [true, false] {
            let mut r = Renderer::new().cull_back_faces(cull);
            r.render_into(
                &odd,
                &Isometry3::translation(0.0, 0.0, 500.0),
                &K,
                Roi::full(64, 48),
            )
            .unwrap();
            assert!(r.depth_mm().iter().all(|d| d.is_finite() && *d >= 0.0));
        }
    }
}
