//! Scene preparation (METHOD.md §2.1–2.3): a depth frame becomes oriented points in millimetres,
//! subsampled like the model, with a kd-tree for pairing within the model diameter.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::camera::{DepthFrame, Intrinsics};
use crate::geometry::render::Roi;
use crate::model::subsample::{subsample, OrientedPoints, SubsampleParams};
use crate::{Error, Result};

/// Parameters of scene preparation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneParams {
    /// Half-size of the window used for normals, mm at the surface; converted to pixels per
    /// point from its depth (clamped to 1..=8 px). Wider is smoother against axial noise (about
    /// 1.5 mm at 1 m for a Kinect) but rounds edges; 5 mm is about 3 px at 1 m on VGA.
    pub normal_radius_mm: f32,
    /// When non-zero, the normal window's half-size in pixels, whatever the depth (replaces
    /// `normal_radius_mm`).
    pub normal_radius_px: u32,
    /// A neighbour `d` pixels away is on the same surface as the centre when their depths
    /// differ by at most what a surface inclined `max_slope_deg` from facing the camera
    /// allows over `d` pixels, `d · (z / fx) · tan(max_slope_deg)`, and never less than
    /// `min_depth_jump_mm` (sensor noise). Farther neighbours are across a depth edge and not used
    /// for smoothing or normals. An absolute threshold instead either mixes surfaces of small parts
    /// or drops steep surfaces (measured on generated views: 45 % of an L-bracket's pixels had no
    /// normal with a 6 mm threshold).
    pub max_slope_deg: f32,
    /// The least depth difference the same-surface rule allows, mm: the sensor's noise.
    pub min_depth_jump_mm: f32,
    /// Depths outside this range are ignored, mm.
    pub min_depth_mm: f32,
    /// The farthest depth kept, mm; `min_depth_mm` is the nearest.
    pub max_depth_mm: f32,
    /// Plane fit: after a first fit, window pixels within this distance of the plane (mm, or
    /// `plane_residual_fraction` of the depth, whichever is larger) make the second fit: it
    /// takes in a slope that the depth-jump rule cut off and drops other surfaces.
    pub plane_residual_mm: f32,
    /// The second fit's distance as a fraction of the pixel's depth (see `plane_residual_mm`).
    pub plane_residual_fraction: f32,
    /// Plane fit: at most this many samples per window row and column (the window is strided
    /// beyond it), which bounds the cost of wide windows.
    pub plane_samples_per_axis: u32,
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            normal_radius_mm: 5.0,
            normal_radius_px: 3,
            max_slope_deg: 75.0,
            min_depth_jump_mm: 3.0,
            min_depth_mm: 100.0,
            max_depth_mm: 5000.0,
            plane_residual_mm: 4.0,
            plane_residual_fraction: 0.004,
            plane_samples_per_axis: 9,
        }
    }
}

impl SceneParams {
    /// Half-size in pixels of the normal window at depth `z_mm` for focal length `fx`.
    #[inline]
    fn normal_window_px(&self, fx: f32, z_mm: f32) -> i64 {
        if self.normal_radius_px > 0 {
            return self.normal_radius_px as i64;
        }
        ((self.normal_radius_mm * fx / z_mm).round() as i64).clamp(1, 8)
    }

    /// The largest depth difference between neighbours `pixels` apart on one surface at depth
    /// `z_mm`, for focal length `fx`; `tan(max_slope_deg)` is given, computed once per frame.
    #[inline]
    fn jump_with_slope_mm(&self, z_mm: f32, pixels: f32, fx: f32, tan_slope: f32) -> f32 {
        (pixels * z_mm / fx * tan_slope).max(self.min_depth_jump_mm)
    }
}

/// Per pixel: the camera-space point and its normal (NaN where either is missing), row-major.
/// What re-scoring, projective ICP and the filters look things up in.
pub struct SceneImage {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The camera's intrinsics.
    pub intrinsics: Intrinsics,
    /// Per pixel, the camera-space point, mm; NaN where there is no depth.
    pub points: Vec<Point3<f32>>,
    /// Per pixel, the unit normal facing the camera; NaN where none was fitted.
    pub normals: Vec<Vector3<f32>>,
    /// Per pixel, the z of `points` alone (NaN where there is none): what re-scoring reads
    /// for every model point it projects, in a third of the bytes, so that more of it stays
    /// in the cache.
    depths: Vec<f32>,
}

impl SceneImage {
    fn of(frame: &DepthFrame, points: Vec<Point3<f32>>, normals: Vec<Vector3<f32>>) -> Self {
        let depths = points.iter().map(|p| p.z).collect();
        SceneImage {
            width: frame.width,
            height: frame.height,
            intrinsics: frame.intrinsics,
            points,
            normals,
            depths,
        }
    }

    /// Per pixel, row-major, the depth (z, mm) of its point, NaN where there is none.
    #[inline]
    pub fn depths(&self) -> &[f32] {
        &self.depths
    }

    /// The point and normal at pixel `(u, v)`, if both exist.
    #[inline]
    pub fn at(&self, u: i64, v: i64) -> Option<(Point3<f32>, Vector3<f32>)> {
        if u < 0 || v < 0 || u >= self.width as i64 || v >= self.height as i64 {
            return None;
        }
        let i = (v as u32 * self.width + u as u32) as usize;
        let n = self.normals[i];
        n.x.is_finite().then(|| (self.points[i], n))
    }

    /// The depth (z, mm) at pixel `(u, v)`, if measured, whether or not it has a normal.
    #[inline]
    pub fn depth(&self, u: i64, v: i64) -> Option<f32> {
        if u < 0 || v < 0 || u >= self.width as i64 || v >= self.height as i64 {
            return None;
        }
        let z = self.depths[(v as u32 * self.width + u as u32) as usize];
        z.is_finite().then_some(z)
    }

    /// The oriented points of every pixel that has both, in pixel order. Gathered on every
    /// core: a VGA frame's pass is 8–10 ms, which the frame's other cores would spend waiting.
    pub fn oriented_points(&self) -> OrientedPoints {
        let (positions, normals) = self
            .points
            .par_iter()
            .zip(&self.normals)
            .filter(|(_, n)| n.x.is_finite())
            .map(|(p, n)| (*p, *n))
            .unzip();
        OrientedPoints { positions, normals }
    }
}

/// The scene prepared for one leaf size: subsampled oriented points and their kd-tree.
pub struct PreparedScene {
    /// The voxel leaf used, mm.
    pub leaf_mm: f32,
    /// The subsampled oriented points, camera coordinates.
    pub points: OrientedPoints,
    /// A kd-tree over `points`, its items their indices.
    pub tree: ImmutableKdTree<f32, 3>,
}

impl PreparedScene {
    /// Subsamples `points` like a model of diameter `leaf_mm / leaf_fraction` and builds the
    /// kd-tree.
    pub fn new(points: &OrientedPoints, subsample_params: &SubsampleParams) -> Result<Self> {
        Self::keeping(points, subsample_params, |_, _| true)
    }

    /// [`PreparedScene::new`] with only the subsampled points that `keep` accepts.
    pub fn keeping(
        points: &OrientedPoints,
        subsample_params: &SubsampleParams,
        keep: impl Fn(&Point3<f32>, &Vector3<f32>) -> bool,
    ) -> Result<Self> {
        let all = subsample(points, subsample_params);
        let mut sub = OrientedPoints::default();
        for (p, n) in all.positions.iter().zip(&all.normals) {
            if keep(p, n) {
                sub.push(*p, *n);
            }
        }
        let coords: Vec<[f32; 3]> = sub.positions.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&coords)
            .map_err(|e| Error::InvalidFrame(format!("cannot index scene points: {e:?}")))?;
        Ok(Self {
            leaf_mm: subsample_params.leaf_mm,
            points: sub,
            tree,
        })
    }

    /// Calls `visit` with the index of every scene point within `radius_mm` of `p`.
    #[inline]
    pub fn within(&self, p: &Point3<f32>, radius_mm: f32, mut visit: impl FnMut(usize)) {
        let q = [p.x, p.y, p.z];
        self.tree
            .query(&q)
            .within::<SquaredEuclidean<f32>>(radius_mm * radius_mm)
            .unsorted()
            .visit(|r| visit(r.item as usize));
    }
}

/// The camera-space point at pixel `(u, v)` of the depth surface `z` with pixel gradient
/// `(zu, zv)` and its unit normal facing the camera.
#[inline]
fn normal_of_plane(
    k: &Intrinsics,
    u: f32,
    v: f32,
    zu: f32,
    zv: f32,
    zc: f32,
) -> Option<(Point3<f32>, Vector3<f32>)> {
    if zc.is_nan() || zc <= 0.0 {
        return None;
    }
    let ray = Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
    let pu = ray * zu + Vector3::new(zc / k.fx, 0.0, 0.0);
    let pv = ray * zv + Vector3::new(0.0, zc / k.fy, 0.0);
    let n = pu.cross(&pv);
    let len = n.norm();
    if len.is_nan() || len <= 1e-12 {
        return None;
    }
    let n = n / len;
    let p = k.backproject(u, v, zc);
    Some((p, if n.dot(&p.coords) > 0.0 { -n } else { n }))
}

/// Per pixel, a least-squares plane `z = a·du + b·dv + c` over the window around it (pixels of
/// other surfaces left out), fitted twice: the camera-space point on the plane (`c` is the
/// smoothed depth) and the plane's normal facing the camera. Structured-light depth comes in
/// steps of 3–4 mm at 1 m; a fit over the whole window sees through the staircase better than
/// differences of two smoothed values. Without depth both are NaN; with too few neighbours on
/// the same surface the point is the measured one and the normal NaN. With `within`, only the
/// pixels inside one of its rectangles are fitted: every other pixel keeps its measured point
/// and no normal.
fn plane_fit(
    frame: &DepthFrame,
    params: &SceneParams,
    within: Option<&[Roi]>,
) -> (Vec<Point3<f32>>, Vec<Vector3<f32>>) {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let r_max = if params.normal_radius_px > 0 {
        params.normal_radius_px as usize
    } else {
        8
    };
    // Depth in mm, NaN where there is none, it is out of range or it lies outside the frame:
    // a border of `r_max` NaN on every side lets a window read its samples without clipping.
    let pw = w + 2 * r_max;
    let mut depth = vec![f32::NAN; pw * (h + 2 * r_max)];
    depth[r_max * pw..(r_max + h) * pw]
        .par_chunks_mut(pw)
        .zip(frame.depth.par_chunks(w))
        .for_each(|(row, raw_row)| {
            for (z_out, &raw) in row[r_max..r_max + w].iter_mut().zip(raw_row) {
                let z = raw as f32 * frame.depth_scale_mm;
                if raw != 0 && z >= params.min_depth_mm && z <= params.max_depth_mm {
                    *z_out = z;
                }
            }
        });
    let fit = PlaneFit {
        depth: &depth,
        pw,
        pad: r_max,
        k: frame.intrinsics,
        params,
        within,
        tan_slope: params.max_slope_deg.to_radians().tan(),
        max_samples: params.plane_samples_per_axis.max(3) as i64,
    };
    let mut points = vec![Point3::new(f32::NAN, f32::NAN, f32::NAN); w * h];
    let mut normals = vec![Vector3::new(f32::NAN, f32::NAN, f32::NAN); w * h];
    points
        .par_chunks_mut(w)
        .zip(normals.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || RowScratch {
                layouts: (0..=r_max).map(|_| None).collect(),
                zn: Vec::new(),
                fitted: Vec::new(),
            },
            |scratch, (v, (points, normals))| fit.row(scratch, v, points, normals),
        );
    (points, normals)
}

/// What fitting one row of the frame reads.
struct PlaneFit<'a> {
    /// Depth in mm with a NaN border `pad` wide, `pw` per row.
    depth: &'a [f32],
    pw: usize,
    pad: usize,
    k: Intrinsics,
    params: &'a SceneParams,
    within: Option<&'a [Roi]>,
    tan_slope: f32,
    max_samples: i64,
}

/// A pixel of the row being fitted: where it is, its measured depth, its window's half-size,
/// the sums of the fit under way and the plane of the last one.
struct Fitted {
    u: usize,
    z: f32,
    r: usize,
    sums: Sums,
    plane: Option<(f32, f32, f32)>,
}

/// One worker's buffers, reused from row to row.
struct RowScratch {
    /// The window of each half-size met so far, by half-size.
    layouts: Vec<Option<Layout>>,
    /// The depths of one window's samples.
    zn: Vec<f32>,
    fitted: Vec<Fitted>,
}

impl PlaneFit<'_> {
    /// The window of half-size `r` (strided to at most `max_samples` per axis).
    fn layout<'s>(&self, layouts: &'s mut [Option<Layout>], r: usize) -> &'s Layout {
        layouts[r].get_or_insert_with(|| {
            let r = r as i64;
            let stride = ((2 * r + 1) + self.max_samples - 1) / self.max_samples;
            Layout::new(r, stride, self.pw)
        })
    }

    /// Points and normals of row `v`. The row goes through each step of the fit in turn (first
    /// sums, first solve, second sums, second solve, normal) rather than one pixel through all
    /// of them: a pixel's steps wait on each other's divisions and square roots, those of
    /// different pixels do not and overlap.
    fn row(
        &self,
        scratch: &mut RowScratch,
        v: usize,
        points: &mut [Point3<f32>],
        normals: &mut [Vector3<f32>],
    ) {
        let RowScratch {
            layouts,
            zn,
            fitted,
        } = scratch;
        let (params, k) = (self.params, &self.k);
        let centre_row = (v + self.pad) * self.pw + self.pad;
        let vf = v as f32;
        fitted.clear();
        // First fit's sums: the neighbours within the jump of the centre.
        for (u, point) in points.iter_mut().enumerate() {
            let z = self.depth[centre_row + u];
            if z.is_nan() {
                continue;
            }
            *point = k.backproject(u as f32, vf, z);
            if self
                .within
                .is_some_and(|rois| !rois.iter().any(|r| r.contains(u as u32, v as u32)))
            {
                continue;
            }
            let r = params.normal_window_px(k.fx, z) as usize;
            let layout = self.layout(layouts, r);
            layout.gather(self.depth, centre_row + u, zn);
            let per_pixel = params.jump_with_slope_mm(z, 1.0, k.fx, self.tan_slope);
            let min_jump = params.min_depth_jump_mm;
            let sums = layout.sums(zn, z, |zn, _du, _dv, d| {
                (zn - z).abs() <= (per_pixel * d).max(min_jump)
            });
            fitted.push(Fitted {
                u,
                z,
                r,
                sums,
                plane: None,
            });
        }
        for f in fitted.iter_mut() {
            f.plane = f.sums.plane(f.z);
        }
        // Second fit: the neighbours near the first plane.
        if params.plane_residual_mm > 0.0 {
            for f in fitted.iter_mut() {
                let Some((a, b, c)) = f.plane else {
                    continue;
                };
                let z = f.z;
                let residual = params
                    .plane_residual_mm
                    .max(params.plane_residual_fraction * z);
                let layout = self.layout(layouts, f.r);
                layout.gather(self.depth, centre_row + f.u, zn);
                f.sums = layout.sums(zn, z, |zn, du, dv, _d| {
                    (zn - (a * du + b * dv + c)).abs() <= residual
                });
            }
            for f in fitted.iter_mut() {
                if f.plane.is_some() {
                    f.plane = f.sums.plane(f.z);
                }
            }
        }
        for f in fitted.iter() {
            let Some((zu, zv, zc)) = f.plane else {
                continue;
            };
            if let Some((p, n)) = normal_of_plane(k, f.u as f32, vf, zu, zv, zc) {
                (points[f.u], normals[f.u]) = (p, n);
            }
        }
    }
}

/// Samples summed side by side in the plane fit.
const LANES: usize = 4;

/// [`LANES`] samples of a window: their positions in the forms the fit uses.
#[derive(Clone, Copy, Default)]
struct Lanes {
    /// `du`, `dv` and `max(|du|, |dv|)` as f32, for the fits' tests.
    du: [f32; LANES],
    dv: [f32; LANES],
    d: [f32; LANES],
    /// `du`, `dv` and their products as integers, for the sums that only depend on which
    /// samples a fit takes.
    idu: [i32; LANES],
    idv: [i32; LANES],
    iuu: [i32; LANES],
    iuv: [i32; LANES],
    ivv: [i32; LANES],
    /// `du`, `dv` as f64, for the sums with depth.
    du64: [f64; LANES],
    dv64: [f64; LANES],
}

/// A window of the plane fit: its samples in row-major order, as offsets in the padded depth
/// image and in groups of [`LANES`]. The samples past the last one, up to whole lanes, are given
/// a NaN depth, which no fit takes.
struct Layout {
    offset: Vec<isize>,
    lanes: Vec<Lanes>,
}

impl Layout {
    /// The window of half-size `r` sampled every `stride` pixels from its corner, in a depth
    /// image `pw` wide.
    fn new(r: i64, stride: i64, pw: usize) -> Self {
        let axis: Vec<i64> = (-r..=r).step_by(stride as usize).collect();
        let positions: Vec<(i64, i64)> = axis
            .iter()
            .flat_map(|&dv| axis.iter().map(move |&du| (du, dv)))
            .collect();
        let offset = positions
            .iter()
            .map(|&(du, dv)| dv as isize * pw as isize + du as isize)
            .collect();
        let mut lanes = vec![Lanes::default(); positions.len().div_ceil(LANES)];
        for (i, &(du, dv)) in positions.iter().enumerate() {
            let (l, j) = (&mut lanes[i / LANES], i % LANES);
            let (fu, fv) = (du as f32, dv as f32);
            l.du[j] = fu;
            l.dv[j] = fv;
            l.d[j] = fu.abs().max(fv.abs());
            let (iu, iv) = (du as i32, dv as i32);
            l.idu[j] = iu;
            l.idv[j] = iv;
            l.iuu[j] = iu * iu;
            l.iuv[j] = iu * iv;
            l.ivv[j] = iv * iv;
            l.du64[j] = du as f64;
            l.dv64[j] = dv as f64;
        }
        Layout { offset, lanes }
    }

    /// Reads into `zn` the depths of the samples of the window around `centre` in the padded
    /// `depth`, NaN past the last one.
    #[inline(always)]
    fn gather(&self, depth: &[f32], centre: usize, zn: &mut Vec<f32>) {
        zn.clear();
        zn.extend(
            self.offset
                .iter()
                .map(|&off| depth[centre.wrapping_add_signed(off)]),
        );
        zn.resize(self.lanes.len() * LANES, f32::NAN);
    }

    /// The sums of the least-squares plane `z = a·du + b·dv + c` through the samples of depth
    /// `zn` that `keep(zn, du, dv, max(|du|, |dv|))` accepts, depths taken relative to the
    /// centre's `z`.
    ///
    /// The sums are accumulated lane by lane and then across lanes, and come out the same as
    /// one sample after another, to the bit. Those of `du`, `dv` and their products are
    /// integers. Every term with depth is `du`, `dv` or 1 times `zn − z` in f32, a multiple of
    /// the f32 spacing at the window's smallest depth; raw depth is 16-bit, so the window's
    /// depths span a ratio below 2¹⁷ and such a sum over `n` samples needs fewer than
    /// 24 + 17 + log₂(r·n) bits, well within f64's 53: each partial sum is exact, in any order.
    #[inline(always)]
    fn sums(&self, zn: &[f32], z: f32, keep: impl Fn(f32, f32, f32, f32) -> bool) -> Sums {
        let (mut n, mut su, mut sv) = ([0i32; LANES], [0i32; LANES], [0i32; LANES]);
        let (mut uu, mut uv, mut vv) = ([0i32; LANES], [0i32; LANES], [0i32; LANES]);
        let (mut sz, mut uz, mut vz) = ([0f64; LANES], [0f64; LANES], [0f64; LANES]);
        for (l, zn) in self.lanes.iter().zip(zn.chunks_exact(LANES)) {
            let zn: &[f32; LANES] = zn.try_into().unwrap();
            // Masks of all ones where a sample is taken, as comparisons give them.
            let mut mask = [0i32; LANES];
            for j in 0..LANES {
                mask[j] = -i32::from(keep(zn[j], l.du[j], l.dv[j], l.d[j]));
            }
            let mut fz = [0f64; LANES];
            for j in 0..LANES {
                fz[j] = f64::from_bits(((zn[j] - z) as f64).to_bits() & (mask[j] as i64 as u64));
            }
            for j in 0..LANES {
                n[j] -= mask[j];
                su[j] += l.idu[j] & mask[j];
                sv[j] += l.idv[j] & mask[j];
                uu[j] += l.iuu[j] & mask[j];
                uv[j] += l.iuv[j] & mask[j];
                vv[j] += l.ivv[j] & mask[j];
            }
            for j in 0..LANES {
                sz[j] += fz[j];
                uz[j] += l.du64[j] * fz[j];
                vz[j] += l.dv64[j] * fz[j];
            }
        }
        let total = |s: [i32; LANES]| s.iter().sum::<i32>();
        let total64 = |s: [f64; LANES]| s.iter().sum::<f64>();
        Sums {
            n: total(n),
            moments: [total(uu), total(uv), total(su), total(vv), total(sv)],
            depth: [total64(uz), total64(vz), total64(sz)],
        }
    }
}
/// The normal equations of a window's plane fit: the samples taken; Σdu², Σdu·dv, Σdu, Σdv²,
/// Σdv; Σdu·z, Σdv·z, Σz.
struct Sums {
    n: i32,
    moments: [i32; 5],
    depth: [f64; 3],
}

impl Sums {
    /// The plane `(a, b, c)` of `z = a·du + b·dv + c`, `c` absolute for the centre depth `z`;
    /// `None` with fewer than four samples or a degenerate layout.
    #[inline(always)]
    fn plane(&self, z: f32) -> Option<(f32, f32, f32)> {
        if self.n < 4 {
            return None;
        }
        let [uu, uv, su, vv, sv] = self.moments.map(f64::from);
        let x = solve_symmetric_3x3([uu, uv, su, vv, sv, f64::from(self.n)], self.depth)?;
        Some((x[0] as f32, x[1] as f32, x[2] as f32 + z))
    }
}

/// Solves `A x = b` for a symmetric positive definite `A` given as its upper triangle
/// `[a00, a01, a02, a11, a12, a22]`, by Cholesky factorisation `A = L Lᵀ` written out for 3 × 3;
/// `None` when `A` is not positive definite (a degenerate window).
#[inline]
fn solve_symmetric_3x3(a: [f64; 6], b: [f64; 3]) -> Option<[f64; 3]> {
    let [a00, a01, a02, a11, a12, a22] = a;
    if a00.is_nan() || a00 <= 0.0 {
        return None;
    }
    let l00 = a00.sqrt();
    let l10 = a01 / l00;
    let l20 = a02 / l00;
    let d1 = a11 - l10 * l10;
    if d1.is_nan() || d1 <= 0.0 {
        return None;
    }
    let l11 = d1.sqrt();
    let l21 = (a12 - l20 * l10) / l11;
    let d2 = a22 - l20 * l20 - l21 * l21;
    if d2.is_nan() || d2 <= 0.0 {
        return None;
    }
    let l22 = d2.sqrt();
    // L y = b, then Lᵀ x = y.
    let y0 = b[0] / l00;
    let y1 = (b[1] - l10 * y0) / l11;
    let y2 = (b[2] - l20 * y0 - l21 * y1) / l22;
    let x2 = y2 / l22;
    let x1 = (y1 - l21 * x2) / l11;
    let x0 = (y0 - l10 * x1 - l20 * x2) / l00;
    Some([x0, x1, x2])
}

/// Validates `frame`, back-projects it and estimates normals; refuses a frame without a single
/// usable point.
pub fn prepare(frame: &DepthFrame, params: &SceneParams) -> Result<SceneImage> {
    frame.validate()?;
    let (points, normals) = plane_fit(frame, params, None);
    if !normals.iter().any(|n| n.x.is_finite()) {
        let valid = points.iter().filter(|p| p.z.is_finite()).count();
        return Err(Error::InvalidFrame(if valid == 0 {
            no_depth_in_range(frame, params)
        } else {
            format!(
                "no surface normal could be estimated in the {}x{} frame: its {valid} pixels of \
                 valid depth have too few neighbours of valid depth on one surface to fit a \
                 normal to (a frame only a few pixels high or wide, or scattered pixels)",
                frame.width, frame.height
            )
        }));
    }
    Ok(SceneImage::of(frame, points, normals))
}

/// [`prepare`] with normals fitted only inside `rois`: every pixel gets its point, and the
/// pixels inside a rectangle the normal the full preparation gives them. What refining known
/// poses needs, which look the scene up only where their objects project; the plane fit is most
/// of a preparation's time. Refuses a frame without valid depth, but not one whose rectangles
/// hold no normal (a pose over a hole in the depth finds nothing there).
pub fn prepare_within(
    frame: &DepthFrame,
    params: &SceneParams,
    rois: &[Roi],
) -> Result<SceneImage> {
    frame.validate()?;
    let (points, normals) = plane_fit(frame, params, Some(rois));
    if !points.iter().any(|p| p.z.is_finite()) {
        return Err(Error::InvalidFrame(no_depth_in_range(frame, params)));
    }
    Ok(SceneImage::of(frame, points, normals))
}

/// Why a frame has no depth in the working range, in words that point at the likely cause: a
/// frame whose values all lie below the range (or above it) by a power of ten is in another unit
/// than its `depth_scale_mm` says (metres as whole numbers, or tenths of a millimetre read as
/// millimetres), and the message names the scale that would bring it into range.
fn no_depth_in_range(frame: &DepthFrame, params: &SceneParams) -> String {
    let (w, h) = (frame.width, frame.height);
    let range = format!("{}..{} mm", params.min_depth_mm, params.max_depth_mm);
    let mut measured: Vec<u16> = frame.depth.iter().copied().filter(|&d| d != 0).collect();
    if measured.is_empty() {
        return format!(
            "no valid depth in the {w}x{h} frame: every value is 0 (no measurement); the \
             working range is {range}"
        );
    }
    let n = measured.len();
    let median = *measured.select_nth_unstable(n / 2).1 as f32;
    let (lo, hi) = (
        *measured.iter().min().unwrap() as f32,
        *measured.iter().max().unwrap() as f32,
    );
    let scale = frame.depth_scale_mm;
    let mut text = format!(
        "no valid depth in the {w}x{h} frame: its {n} measured values run {lo}..{hi} (median \
         {median}), times depth_scale_mm {scale} that is {}..{} mm, all outside the working \
         range {range}",
        lo * scale,
        hi * scale
    );
    // The power of ten that puts the median in the range, the usual units of depth cameras
    // first (metres, tenths of a millimetre, centimetres).
    let fitting = [1000.0, 0.1, 10.0, 0.01, 100.0, 0.001, 10_000.0]
        .into_iter()
        .map(|k: f32| scale * k)
        .find(|s| (params.min_depth_mm..=params.max_depth_mm).contains(&(median * s)));
    if let Some(s) = fitting {
        let unit = match s {
            s if (s - 1000.0).abs() < 1e-3 => " (the values are metres)",
            s if (s - 10.0).abs() < 1e-5 => " (the values are centimetres)",
            s if (s - 0.1).abs() < 1e-7 => " (the values are tenths of a millimetre)",
            _ => "",
        };
        text.push_str(&format!(
            "; with depth_scale_mm {s} the median would be {} mm{unit}: is the frame's \
             depth_scale_mm right?",
            median * s
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`prepare`], then the oriented points of every pixel that has both.
    fn prepare_points(frame: &DepthFrame, params: &SceneParams) -> Result<OrientedPoints> {
        Ok(prepare(frame, params)?.oriented_points())
    }

    fn plane_frame(z_of: impl Fn(f32, f32) -> f32) -> (Vec<u16>, Intrinsics) {
        let k = Intrinsics::LMO;
        let mut depth = vec![0u16; 640 * 480];
        for v in 0..480 {
            for u in 0..640 {
                depth[v * 640 + u] = z_of(u as f32, v as f32).round() as u16;
            }
        }
        (depth, k)
    }

    /// The plane fit as first written, sample after sample into a growing window: what the
    /// laned [`plane_fit`] must give to the bit.
    fn plane_fit_reference(
        frame: &DepthFrame,
        params: &SceneParams,
        within: Option<&[Roi]>,
    ) -> (Vec<Point3<f32>>, Vec<Vector3<f32>>) {
        let (w, h) = (frame.width as i64, frame.height as i64);
        let k = frame.intrinsics;
        // Depth in mm, NaN where there is none or it is out of range: one load per window sample.
        let depth: Vec<f32> = frame
            .depth
            .par_iter()
            .map(|&raw| {
                let z = raw as f32 * frame.depth_scale_mm;
                if raw != 0 && z >= params.min_depth_mm && z <= params.max_depth_mm {
                    z
                } else {
                    f32::NAN
                }
            })
            .collect();
        let depth = &depth;
        let tan_slope = params.max_slope_deg.to_radians().tan();
        let nan_p = Point3::new(f32::NAN, f32::NAN, f32::NAN);
        let nan_n = Vector3::new(f32::NAN, f32::NAN, f32::NAN);
        let max_samples = params.plane_samples_per_axis.max(3) as i64;
        let out: Vec<(Point3<f32>, Vector3<f32>)> = (0..h)
            .into_par_iter()
            .flat_map_iter(|v| {
                // The samples of one pixel's window, reused along the row.
                let mut window: Vec<(f32, f32, f32)> = Vec::new();
                (0..w).map(move |u| {
                    let z = depth[(v * w + u) as usize];
                    if z.is_nan() {
                        return (nan_p, nan_n);
                    }
                    let raw_point = k.backproject(u as f32, v as f32, z);
                    if within
                        .is_some_and(|rois| !rois.iter().any(|r| r.contains(u as u32, v as u32)))
                    {
                        return (raw_point, nan_n);
                    }
                    let r = params.normal_window_px(k.fx, z);
                    let stride = ((2 * r + 1) + max_samples - 1) / max_samples;
                    let per_pixel = params.jump_with_slope_mm(z, 1.0, k.fx, tan_slope);
                    let residual = params
                        .plane_residual_mm
                        .max(params.plane_residual_fraction * z);
                    // The window's samples with depth, gathered once for both fits.
                    window.clear();
                    let (x0, x1) = ((u - r).max(0), (u + r).min(w - 1));
                    let x_start = x0 + (u - r - x0).rem_euclid(stride); // on the stride grid from u − r
                    let mut dv = -r;
                    while dv <= r {
                        let y = v + dv;
                        if y >= 0 && y < h {
                            let row = &depth[(y * w) as usize..((y + 1) * w) as usize];
                            let mut x = x_start;
                            while x <= x1 {
                                let zn = row[x as usize];
                                if !zn.is_nan() {
                                    window.push(((x - u) as f32, dv as f32, zn));
                                }
                                x += stride;
                            }
                        }
                        dv += stride;
                    }
                    // Two fits: neighbours within the jump of the centre, then those near the plane.
                    let jump = |du: f32, dv: f32, zn: f32| {
                        let d = du.abs().max(dv.abs());
                        (zn - z).abs() <= (per_pixel * d).max(params.min_depth_jump_mm)
                    };
                    let Some(first) = fit_window_reference(&window, z, jump) else {
                        return (raw_point, nan_n);
                    };
                    let mut plane = first;
                    if params.plane_residual_mm > 0.0 {
                        let (a, bb, c) = first;
                        let near = |du: f32, dv: f32, zn: f32| {
                            (zn - (a * du + bb * dv + c)).abs() <= residual
                        };
                        let Some(second) = fit_window_reference(&window, z, near) else {
                            return (raw_point, nan_n);
                        };
                        plane = second;
                    }
                    let (zu, zv, zc) = plane;
                    normal_of_plane(&k, u as f32, v as f32, zu, zv, zc)
                        .unwrap_or((raw_point, nan_n))
                })
            })
            .collect();
        out.into_iter().unzip()
    }

    /// [`Window::fit`] sample after sample, in f64.
    fn fit_window_reference(
        window: &[(f32, f32, f32)],
        z: f32,
        keep: impl Fn(f32, f32, f32) -> bool,
    ) -> Option<(f32, f32, f32)> {
        // Σdu², Σdu·dv, Σdu, Σdv², Σdv, n; Σdu·z, Σdv·z, Σz, as locals so that they stay in
        // registers.
        let (mut uu, mut uv, mut su, mut vv, mut sv, mut n) = (0f64, 0f64, 0f64, 0f64, 0f64, 0f64);
        let (mut uz, mut vz, mut sz) = (0f64, 0f64, 0f64);
        for &(du, dv, zn) in window {
            if keep(du, dv, zn) {
                let (fu, fv, fz) = (du as f64, dv as f64, (zn - z) as f64);
                uu += fu * fu;
                uv += fu * fv;
                su += fu;
                vv += fv * fv;
                sv += fv;
                n += 1.0;
                uz += fu * fz;
                vz += fv * fz;
                sz += fz;
            }
        }
        if n < 4.0 {
            return None;
        }
        let x = solve_symmetric_3x3([uu, uv, su, vv, sv, n], [uz, vz, sz])?;
        Some((x[0] as f32, x[1] as f32, x[2] as f32 + z))
    }

    /// `plane_fit` and `plane_fit_reference` agree on every pixel, points and normals to the bit.
    fn assert_same_fit(frame: &DepthFrame, params: &SceneParams, within: Option<&[Roi]>) {
        let (points, normals) = plane_fit(frame, params, within);
        let (ref_points, ref_normals) = plane_fit_reference(frame, params, within);
        assert_eq!(points.len(), ref_points.len());
        let mut fitted = 0;
        for i in 0..points.len() {
            let (u, v) = (i as u32 % frame.width, i as u32 / frame.width);
            assert_eq!(
                points[i].coords.map(f32::to_bits),
                ref_points[i].coords.map(f32::to_bits),
                "point at ({u}, {v}) with {params:?}"
            );
            assert_eq!(
                normals[i].map(f32::to_bits),
                ref_normals[i].map(f32::to_bits),
                "normal at ({u}, {v}) with {params:?}"
            );
            fitted += usize::from(normals[i].x.is_finite());
        }
        if frame.width * frame.height > 10_000 {
            assert!(fitted > 1000, "{fitted} normals with {params:?}");
        }
    }

    /// The defaults, a window in millimetres, a strided one, a single fit and wider strides.
    fn fit_variants() -> Vec<SceneParams> {
        let d = SceneParams::default();
        vec![
            d,
            SceneParams {
                normal_radius_px: 0,
                ..d
            },
            SceneParams {
                normal_radius_px: 5,
                ..d
            },
            SceneParams {
                plane_residual_mm: 0.0,
                ..d
            },
            SceneParams {
                normal_radius_px: 7,
                plane_samples_per_axis: 4,
                ..d
            },
            SceneParams {
                normal_radius_px: 1,
                min_depth_jump_mm: 0.5,
                ..d
            },
        ]
    }

    /// On the real LM-O frame (a Kinect's depth, tenths of a millimetre).
    #[test]
    fn plane_fit_matches_reference_on_the_lmo_frame() {
        let Some(dir) = ppfd_bop::shared_test_data("lmo") else {
            return;
        };
        let dataset = ppfd_bop::dataset::BopDataset::open(&dir).unwrap();
        // The BOP reader's frame is of the library as a dependency; its fields make this one's.
        let owned = dataset.depth_frame(2, 3).unwrap();
        let frame = DepthFrame {
            width: owned.width,
            height: owned.height,
            intrinsics: Intrinsics {
                fx: owned.intrinsics.fx,
                fy: owned.intrinsics.fy,
                cx: owned.intrinsics.cx,
                cy: owned.intrinsics.cy,
            },
            depth_scale_mm: owned.depth_scale_mm,
            depth: &owned.depth,
        };
        for params in fit_variants() {
            assert_same_fit(&frame, &params, None);
        }
        let rois = [Roi {
            u0: 200,
            v0: 150,
            width: 200,
            height: 120,
        }];
        assert_same_fit(&frame, &SceneParams::default(), Some(&rois));
    }

    /// On generated frames: each part alone with Kinect noise, a cluttered table, and frames a
    /// few pixels wide or high, where every window is clipped.
    #[test]
    fn plane_fit_matches_reference_on_generated_frames() {
        use crate::synthetic::parts::Part;
        use crate::synthetic::scene::{NoiseModel, SceneSpec, SyntheticScene};
        let noise = NoiseModel::kinect();
        let meshes: Vec<_> = Part::ALL.iter().map(|p| p.mesh()).collect();
        for (i, mesh) in meshes.iter().enumerate() {
            let pose = crate::Pose::from_parts(
                nalgebra::Translation3::new(20.0, -10.0, 500.0 + 300.0 * i as f32),
                nalgebra::UnitQuaternion::from_euler_angles(0.4, -0.3 * i as f32, 0.2),
            );
            let scene = SyntheticScene::single(mesh, 1, pose, Some(&noise), 4).unwrap();
            for params in fit_variants() {
                assert_same_fit(&scene.frame.view(), &params, None);
            }
        }
        let mut spec = SceneSpec::new(7).noise(Some(noise)).clutter(6);
        for (i, mesh) in meshes.iter().enumerate() {
            spec = spec.object(i as u32 + 1, mesh);
        }
        let scene = spec.build().unwrap();
        let frame = scene.frame.view();
        for params in fit_variants() {
            assert_same_fit(&frame, &params, None);
        }
        // Crops of the cluttered frame: 3 × 480, 640 × 2 and 9 × 5 pixels.
        for (u0, v0, cw, ch) in [(300, 0, 3, 480), (0, 240, 640, 2), (320, 200, 9, 5)] {
            let depth: Vec<u16> = (v0..v0 + ch)
                .flat_map(|v| (u0..u0 + cw).map(move |u| (u, v)))
                .map(|(u, v)| frame.depth[v * 640 + u])
                .collect();
            let crop = DepthFrame {
                width: cw as u32,
                height: ch as u32,
                depth: &depth,
                ..frame
            };
            for params in fit_variants() {
                assert_same_fit(&crop, &params, None);
            }
        }
    }

    /// The written-out 3 × 3 Cholesky solve gives what nalgebra's gives on the plane fit's
    /// normal equations (to an f64 rounding, far below the f32 the fit returns), and refuses
    /// what nalgebra refuses.
    #[test]
    fn symmetric_solve_matches_nalgebra() {
        let mut rng = crate::geometry::rng::Rng::new(9);
        for _ in 0..1000 {
            // The normal equations of a 7 × 7 window with some samples left out.
            let (mut a, mut b) = ([0f64; 6], [0f64; 3]);
            for du in -3..=3 {
                for dv in -3..=3 {
                    if rng.uniform() < 0.3 {
                        continue;
                    }
                    let (u, v, z) = (du as f64, dv as f64, 20.0 * (rng.uniform() - 0.5));
                    let row = [u * u, u * v, u, v * v, v, 1.0];
                    for k in 0..6 {
                        a[k] += row[k];
                    }
                    b[0] += u * z;
                    b[1] += v * z;
                    b[2] += z;
                }
            }
            let m = nalgebra::Matrix3::new(a[0], a[1], a[2], a[1], a[3], a[4], a[2], a[4], a[5]);
            let expected = m
                .cholesky()
                .map(|c| c.solve(&nalgebra::Vector3::new(b[0], b[1], b[2])));
            let got = solve_symmetric_3x3(a, b);
            match (expected, got) {
                (Some(e), Some(g)) => {
                    for k in 0..3 {
                        assert!(
                            (e[k] - g[k]).abs() <= 1e-12 * e[k].abs().max(1.0),
                            "{e} {g:?}"
                        );
                    }
                }
                (None, None) => {}
                (e, g) => panic!("nalgebra {e:?}, written out {g:?}"),
            }
        }
        // Samples on one line: no plane.
        let line = [4.0, 4.0, 2.0, 4.0, 2.0, 2.0];
        assert!(solve_symmetric_3x3(line, [1.0, 1.0, 1.0]).is_none());
        assert!(
            nalgebra::Matrix3::new(4.0, 4.0, 2.0, 4.0, 4.0, 2.0, 2.0, 2.0, 2.0)
                .cholesky()
                .is_none()
        );
    }

    #[test]
    fn frontal_plane_gives_normals_towards_the_camera() {
        let (depth, k) = plane_frame(|_, _| 800.0);
        let frame = DepthFrame {
            width: 640,
            height: 480,
            intrinsics: k,
            depth_scale_mm: 1.0,
            depth: &depth,
        };
        let pts = prepare_points(&frame, &SceneParams::default()).unwrap();
        assert_eq!(pts.len(), 640 * 480);
        let worst = pts
            .normals
            .iter()
            .map(|n| (n - Vector3::new(0.0, 0.0, -1.0)).norm())
            .fold(0.0, f32::max);
        assert!(worst < 1e-3, "worst normal off by {worst}");
        let c = pts.positions[240 * 640 + 320];
        assert!((c.z - 800.0).abs() < 1e-3 && (c.x - (320.0 - k.cx) * 800.0 / k.fx).abs() < 1e-3);
    }

    #[test]
    fn tilted_plane_normal_is_recovered() {
        // z = 800 + 0.5 * x_cam: a plane turned about y; its normal is (0.5, 0, -1) normalised.
        let k = Intrinsics::LMO;
        let (depth, _) = plane_frame(|u, _| {
            // Solve z = 800 + 0.5 * (u - cx) z / fx for z.
            800.0 / (1.0 - 0.5 * (u - k.cx) / k.fx)
        });
        let frame = DepthFrame {
            width: 640,
            height: 480,
            intrinsics: k,
            depth_scale_mm: 0.1,
            depth: &depth.iter().map(|&d| d * 10).collect::<Vec<_>>(),
        };
        let pts = prepare_points(&frame, &SceneParams::default()).unwrap();
        let expected = Vector3::new(0.5, 0.0, -1.0).normalize();
        let mean: Vector3<f32> = pts.normals.iter().sum::<Vector3<f32>>() / pts.len() as f32;
        assert!((mean.normalize() - expected).norm() < 0.02, "{mean:?}");
    }

    #[test]
    fn empty_and_malformed_frames_are_refused() {
        let depth = vec![0u16; 640 * 480];
        let mut frame = DepthFrame {
            width: 640,
            height: 480,
            intrinsics: Intrinsics::LMO,
            depth_scale_mm: 1.0,
            depth: &depth,
        };
        assert!(
            matches!(prepare_points(&frame, &SceneParams::default()), Err(Error::InvalidFrame(m)) if m.contains("no valid depth"))
        );
        frame.depth = &depth[..1024];
        assert!(
            matches!(prepare_points(&frame, &SceneParams::default()), Err(Error::InvalidFrame(m)) if m.contains("needs 307200 values, got 1024"))
        );
        frame.depth = &depth;
        frame.intrinsics.fx = f32::NAN;
        assert!(prepare_points(&frame, &SceneParams::default()).is_err());
        frame.intrinsics = Intrinsics {
            fx: 0.0,
            ..Intrinsics::LMO
        };
        assert!(prepare_points(&frame, &SceneParams::default()).is_err());
        // Valid depth, but one row: no window to fit a normal in.
        let row = vec![850u16; 640];
        let thin = DepthFrame {
            width: 640,
            height: 1,
            intrinsics: Intrinsics {
                cy: 0.0,
                ..Intrinsics::LMO
            },
            depth_scale_mm: 1.0,
            depth: &row,
        };
        let err = prepare_points(&thin, &SceneParams::default()).unwrap_err();
        assert!(
            err.to_string().contains("no surface normal") && err.to_string().contains("640 pixels"),
            "{err}"
        );
    }

    /// Inside the rectangles, the normals and points of the full preparation, to the bit;
    /// outside, the measured point and no normal; a frame without depth is still refused.
    #[test]
    fn preparing_within_rectangles_fits_normals_there_only() {
        let part = crate::synthetic::parts::Part::TPipe;
        let pose = crate::Pose::from_parts(
            nalgebra::Translation3::new(20.0, -10.0, 750.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.4, -0.3, 0.2),
        );
        let noise = crate::synthetic::scene::NoiseModel::kinect();
        let scene =
            crate::synthetic::scene::SyntheticScene::single(&part.mesh(), 1, pose, Some(&noise), 4)
                .unwrap();
        let frame = scene.frame.view();
        let params = SceneParams::default();
        let full = prepare(&frame, &params).unwrap();
        let rois = [
            Roi {
                u0: 250,
                v0: 170,
                width: 80,
                height: 60,
            },
            Roi {
                u0: 300,
                v0: 200,
                width: 90,
                height: 100,
            },
        ];
        let part_image = prepare_within(&frame, &params, &rois).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for v in 0..480u32 {
            for u in 0..640u32 {
                let i = (v * 640 + u) as usize;
                let (p, n) = (part_image.points[i], part_image.normals[i]);
                if rois.iter().any(|r| r.contains(u, v)) {
                    assert_eq!(
                        p.coords.map(f32::to_bits),
                        full.points[i].coords.map(f32::to_bits)
                    );
                    assert_eq!(n.map(f32::to_bits), full.normals[i].map(f32::to_bits));
                    inside += usize::from(n.x.is_finite());
                } else {
                    assert!(n.x.is_nan(), "a normal outside at ({u}, {v})");
                    let raw = frame.depth[i];
                    if raw != 0 {
                        let expected = frame.intrinsics.backproject(u as f32, v as f32, raw as f32);
                        assert!((p - expected).norm() < 1e-3, "({u}, {v}): {p} {expected}");
                        outside += 1;
                    } else {
                        assert!(p.z.is_nan());
                    }
                }
            }
        }
        assert!(inside > 3000 && outside > 500, "{inside} {outside}");

        let empty = vec![0u16; 640 * 480];
        let no_depth = DepthFrame {
            depth: &empty,
            ..frame
        };
        match prepare_within(&no_depth, &params, &rois) {
            Err(e) => assert!(e.to_string().contains("no valid depth"), "{e}"),
            Ok(_) => panic!("a frame without depth was prepared"),
        }
    }

    /// A frame whose values are in another unit than its scale says is refused with the range
    /// it holds and the scale that fits; a frame without a single measurement says so.
    #[test]
    fn depth_in_another_unit_is_refused_with_the_scale_that_fits() {
        let params = SceneParams::default();
        let refusal = |depth: &[u16], scale: f32| {
            let frame = DepthFrame {
                width: 640,
                height: 480,
                intrinsics: Intrinsics::LMO,
                depth_scale_mm: scale,
                depth,
            };
            match prepare(&frame, &params) {
                Err(Error::InvalidFrame(m)) => m,
                other => panic!("not refused: {:?}", other.map(|_| ())),
            }
        };
        // Metres as whole numbers: a wall 2 m away reads 2.
        let m = refusal(&vec![2u16; 640 * 480], 1.0);
        assert!(
            m.contains("2..2 mm") && m.contains("depth_scale_mm 1000") && m.contains("metres"),
            "{m}"
        );
        // Tenths of a millimetre read as millimetres: 8 m, beyond the range.
        let m = refusal(&vec![8000u16; 640 * 480], 1.0);
        assert!(
            m.contains("depth_scale_mm 0.1") && m.contains("tenths of a millimetre"),
            "{m}"
        );
        let m = refusal(&vec![0u16; 640 * 480], 1.0);
        assert!(m.contains("every value is 0"), "{m}");
    }

    /// The depth scale is applied before anything else: a scene in tenths of a millimetre gives
    /// the points and normals of the same scene in millimetres.
    #[test]
    fn a_scene_in_tenths_of_a_millimetre_gives_the_points_of_the_same_scene_in_millimetres() {
        let (mm, _) = plane_frame(|u, v| 700.0 + 0.4 * u + 0.2 * v);
        let tenths: Vec<u16> = mm.iter().map(|&d| d * 10).collect();
        fn frame(depth: &[u16], scale: f32) -> DepthFrame<'_> {
            DepthFrame {
                width: 640,
                height: 480,
                intrinsics: Intrinsics::LMO,
                depth_scale_mm: scale,
                depth,
            }
        }
        let a = prepare(&frame(&mm, 1.0), &SceneParams::default()).unwrap();
        let b = prepare(&frame(&tenths, 0.1), &SceneParams::default()).unwrap();
        let (mut points, mut worst_p, mut worst_n) = (0, 0f32, 0f32);
        for i in 0..a.points.len() {
            if a.normals[i].x.is_finite() {
                points += 1;
                worst_p = worst_p.max((a.points[i] - b.points[i]).norm());
                worst_n = worst_n.max((a.normals[i] - b.normals[i]).norm());
            } else {
                assert!(!b.normals[i].x.is_finite());
            }
        }
        assert!(points > 300_000, "{points}");
        assert!(worst_p < 1e-3 && worst_n < 1e-4, "{worst_p} mm, {worst_n}");
    }

    /// Pixels without depth (0) or outside the working range give no point and are no one's
    /// neighbour; the surface around them keeps its normals.
    #[test]
    fn missing_and_out_of_range_depth_is_left_out() {
        let params = SceneParams::default();
        let (mut depth, k) = plane_frame(|_, _| 900.0);
        // A hole, a patch beyond the range and one before it, each 40 × 40 pixels.
        for (u0, value) in [(100, 0u16), (300, 6000), (500, 50)] {
            for v in 200..240 {
                for u in u0..u0 + 40 {
                    depth[v * 640 + u] = value;
                }
            }
        }
        let frame = DepthFrame {
            width: 640,
            height: 480,
            intrinsics: k,
            depth_scale_mm: 1.0,
            depth: &depth,
        };
        let image = prepare(&frame, &params).unwrap();
        for u0 in [100i64, 300, 500] {
            for (u, v) in [(u0, 200i64), (u0 + 20, 220), (u0 + 39, 239)] {
                assert!(
                    image.depth(u, v).is_none() && image.at(u, v).is_none(),
                    "({u}, {v})"
                );
            }
            // Right beside the patch: the plane's point and normal, undisturbed.
            let (p, n) = image.at(u0 - 1, 220).expect("a normal beside the patch");
            assert!((p.z - 900.0).abs() < 1e-3, "{p}");
            assert!((n - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-3, "{n}");
        }
        let with_points = image.normals.iter().filter(|n| n.x.is_finite()).count();
        assert_eq!(with_points, 640 * 480 - 3 * 40 * 40);
    }

    #[test]
    fn kd_tree_finds_points_within_radius() {
        let mut pts = OrientedPoints::default();
        for i in 0..50 {
            for j in 0..50 {
                pts.push(
                    Point3::new(i as f32 * 4.0, j as f32 * 4.0, 500.0),
                    -Vector3::z(),
                );
            }
        }
        let params = SubsampleParams {
            leaf_mm: 4.0,
            cluster_angle: 0.5,
            neighbour_filtering: false,
        };
        let scene = PreparedScene::new(&pts, &params).unwrap();
        let q = scene.points.positions[0];
        let mut found = Vec::new();
        scene.within(&q, 30.0, |i| found.push(i));
        let brute = scene
            .points
            .positions
            .iter()
            .filter(|p| (*p - q).norm() <= 30.0)
            .count();
        assert_eq!(found.len(), brute);
        assert!(found
            .iter()
            .all(|&i| (scene.points.positions[i] - q).norm() <= 30.0 + 1e-3));
    }
}
