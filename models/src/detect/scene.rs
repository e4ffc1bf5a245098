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
    pub min_depth_jump_mm: f32,
    /// Depths outside this range are ignored, mm.
    pub min_depth_mm: f32,
    pub max_depth_mm: f32,
    /// Plane fit: after a first fit, window pixels within this distance of the plane (mm, or
    /// `plane_residual_fraction` of the depth, whichever is larger) make the second fit: it
    /// takes in a slope that the depth-jump rule cut off and drops other surfaces.
    pub plane_residual_mm: f32,
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
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub points: Vec<Point3<f32>>,
    pub normals: Vec<Vector3<f32>>,
}

impl SceneImage {
    fn of(frame: &DepthFrame, points: Vec<Point3<f32>>, normals: Vec<Vector3<f32>>) -> Self {
        SceneImage {
            width: frame.width,
            height: frame.height,
            intrinsics: frame.intrinsics,
            points,
            normals,
        }
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
        let z = self.points[(v as u32 * self.width + u as u32) as usize].z;
        z.is_finite().then_some(z)
    }

    /// The oriented points of every pixel that has both.
    pub fn oriented_points(&self) -> OrientedPoints {
        let mut out = OrientedPoints::default();
        for (p, n) in self.points.iter().zip(&self.normals) {
            if n.x.is_finite() {
                out.push(*p, *n);
            }
        }
        out
    }
}

/// The scene prepared for one leaf size: subsampled oriented points and their kd-tree.
pub struct PreparedScene {
    /// The voxel leaf used, mm.
    pub leaf_mm: f32,
    pub points: OrientedPoints,
    pub tree: ImmutableKdTree<f32, 3>,
}

impl PreparedScene {
    /// Subsamples `points` like a model of diameter `leaf_mm / leaf_fraction` and builds the
    /// kd-tree.
    pub fn new(points: &OrientedPoints, subsample_params: &SubsampleParams) -> Result<Self> {
        let sub = subsample(points, subsample_params);
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
                if within.is_some_and(|rois| !rois.iter().any(|r| r.contains(u as u32, v as u32))) {
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
                let Some(first) = fit_window(&window, z, jump) else {
                    return (raw_point, nan_n);
                };
                let mut plane = first;
                if params.plane_residual_mm > 0.0 {
                    let (a, bb, c) = first;
                    let near =
                        |du: f32, dv: f32, zn: f32| (zn - (a * du + bb * dv + c)).abs() <= residual;
                    let Some(second) = fit_window(&window, z, near) else {
                        return (raw_point, nan_n);
                    };
                    plane = second;
                }
                let (zu, zv, zc) = plane;
                normal_of_plane(&k, u as f32, v as f32, zu, zv, zc).unwrap_or((raw_point, nan_n))
            })
        })
        .collect();
    out.into_iter().unzip()
}

/// The least-squares plane `z = a·du + b·dv + c` through the window samples `(du, dv, z)` that
/// `keep` accepts, depths taken relative to the centre's `z` (and `c` returned absolute);
/// `None` with fewer than four samples or a degenerate layout.
#[inline]
fn fit_window(
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
            intrinsics: Intrinsics::LMO,
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
