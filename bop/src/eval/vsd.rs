//! Visible Surface Discrepancy (Hodaň et al. 2016), as the BOP toolkit's `pose_error.vsd`
//! computes it.
//!
//! The object is rendered at the estimated and at the true pose. The three depth images (test,
//! true, estimated) become distance maps: the distance from the camera centre to the surface
//! point seen at each pixel, not its z ([`depth_to_distance`]). A rendered pixel is *visible*
//! where it is not more than δ behind the test surface ([`visibility_mask`]); the estimate's
//! visible mask also takes the pixels visible at the true pose that the estimate covers
//! ([`visibility_mask_est`]). Over the union of the two visible masks, a pixel costs 1 where it is
//! outside their intersection or where the two renderings differ by τ or more; VSD is the mean
//! cost ([`vsd_errors`]). An empty union costs 1.

use crate::{Error, Result};
use ppfd_models::geometry::camera::Intrinsics;

/// How a rendered pixel is judged visible against the test image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum VisibilityMode {
    /// The SIXD/BOP 2018 rule: the model pixel and the test pixel both have a distance, and the
    /// model is at most δ behind the test surface.
    Bop18,
    /// The BOP 2019 rule: the model pixel has a distance, and either the model is at most δ
    /// behind the test surface or the test image has no measurement there.
    Bop19,
}

/// Per-pixel matching cost inside the intersection of the visible masks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum CostType {
    /// 1 where the distances differ by τ or more, else 0 (BOP's `'step'`, the benchmark's).
    Step,
    /// `min(1, |difference| / τ)` (BOP's `'tlinear'`).
    TruncatedLinear,
}

/// Converts a depth image (camera z, mm, 0 = none) into a distance map: at pixel `(u, v)`,
/// `z·√(((u − cx)/fx)² + ((v − cy)/fy)² + 1)`, the distance from the camera centre; 0 stays 0.
pub fn depth_to_distance(
    depth_mm: &[f32],
    width: u32,
    height: u32,
    intrinsics: &Intrinsics,
) -> Result<Vec<f32>> {
    check_len(depth_mm.len(), width, height, "depth image")?;
    intrinsics.validate_for(width, height)?;
    let (fx, fy) = (intrinsics.fx as f64, intrinsics.fy as f64);
    let (cx, cy) = (intrinsics.cx as f64, intrinsics.cy as f64);
    let xs: Vec<f64> = (0..width).map(|u| (u as f64 - cx) / fx).collect();
    let mut out = vec![0.0f32; depth_mm.len()];
    for v in 0..height as usize {
        let y = (v as f64 - cy) / fy;
        let row = v * width as usize;
        for (u, x) in xs.iter().enumerate() {
            let z = depth_mm[row + u] as f64;
            if z != 0.0 {
                out[row + u] = (z * (x * x + y * y + 1.0).sqrt()) as f32;
            }
        }
    }
    Ok(out)
}

/// Whether one rendered pixel is visible against the test pixel (both distances, mm).
#[inline]
fn visible(dist_test: f32, dist_model: f32, delta_mm: f32, mode: VisibilityMode) -> bool {
    let behind_by = dist_model - dist_test;
    match mode {
        VisibilityMode::Bop18 => dist_test > 0.0 && dist_model > 0.0 && behind_by <= delta_mm,
        VisibilityMode::Bop19 => dist_model > 0.0 && (behind_by <= delta_mm || dist_test == 0.0),
    }
}

/// The visible mask of a rendered object (BOP's `estimate_visib_mask_gt`, also the first part
/// of `estimate_visib_mask_est`).
pub fn visibility_mask(
    dist_test: &[f32],
    dist_model: &[f32],
    delta_mm: f32,
    mode: VisibilityMode,
) -> Result<Vec<bool>> {
    check_same(dist_test.len(), dist_model.len())?;
    Ok(dist_test
        .iter()
        .zip(dist_model)
        .map(|(&t, &m)| visible(t, m, delta_mm, mode))
        .collect())
}

/// The visible mask of the object at the estimated pose: [`visibility_mask`] plus the pixels of
/// `visib_gt` that the estimate covers (BOP's `estimate_visib_mask_est`).
pub fn visibility_mask_est(
    dist_test: &[f32],
    dist_est: &[f32],
    visib_gt: &[bool],
    delta_mm: f32,
    mode: VisibilityMode,
) -> Result<Vec<bool>> {
    check_same(dist_test.len(), dist_est.len())?;
    check_same(dist_test.len(), visib_gt.len())?;
    Ok(dist_test
        .iter()
        .zip(dist_est)
        .zip(visib_gt)
        .map(|((&t, &e), &g)| visible(t, e, delta_mm, mode) || (g && e > 0.0))
        .collect())
}

/// VSD for each misalignment tolerance in `taus_mm`, from three distance maps of one size.
///
/// `delta_mm` is the visibility tolerance δ. Each error is in `[0, 1]`; 1 when neither rendering
/// is visible anywhere.
pub fn vsd_errors(
    dist_test: &[f32],
    dist_gt: &[f32],
    dist_est: &[f32],
    delta_mm: f32,
    taus_mm: &[f32],
    mode: VisibilityMode,
    cost: CostType,
) -> Result<Vec<f32>> {
    check_same(dist_test.len(), dist_gt.len())?;
    check_same(dist_test.len(), dist_est.len())?;
    if let Some(tau) = taus_mm.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
        return Err(Error::InvalidParameter(format!(
            "VSD tolerance tau must be positive and finite, got {tau}"
        )));
    }
    let mut union = 0usize;
    let mut differences = Vec::new();
    for ((&t, &g), &e) in dist_test.iter().zip(dist_gt).zip(dist_est) {
        if g == 0.0 && e == 0.0 {
            continue;
        }
        let visib_gt = visible(t, g, delta_mm, mode);
        let visib_est = visible(t, e, delta_mm, mode) || (visib_gt && e > 0.0);
        if visib_gt || visib_est {
            union += 1;
        }
        if visib_gt && visib_est {
            differences.push((g as f64 - e as f64).abs());
        }
    }
    if union == 0 {
        return Ok(vec![1.0; taus_mm.len()]);
    }
    let outside_intersection = (union - differences.len()) as f64;
    Ok(taus_mm
        .iter()
        .map(|&tau| {
            let tau = tau as f64;
            let costs: f64 = match cost {
                CostType::Step => differences.iter().filter(|&&d| d >= tau).count() as f64,
                CostType::TruncatedLinear => differences.iter().map(|d| (d / tau).min(1.0)).sum(),
            };
            ((costs + outside_intersection) / union as f64) as f32
        })
        .collect())
}

/// VSD from depth images (camera z, mm, 0 = none) of one size: converts them with
/// [`depth_to_distance`], then [`vsd_errors`].
#[allow(clippy::too_many_arguments)]
pub fn vsd(
    depth_test: &[f32],
    depth_gt: &[f32],
    depth_est: &[f32],
    width: u32,
    height: u32,
    intrinsics: &Intrinsics,
    delta_mm: f32,
    taus_mm: &[f32],
    mode: VisibilityMode,
    cost: CostType,
) -> Result<Vec<f32>> {
    let test = depth_to_distance(depth_test, width, height, intrinsics)?;
    let gt = depth_to_distance(depth_gt, width, height, intrinsics)?;
    let est = depth_to_distance(depth_est, width, height, intrinsics)?;
    vsd_errors(&test, &gt, &est, delta_mm, taus_mm, mode, cost)
}

fn check_len(len: usize, width: u32, height: u32, what: &str) -> Result<()> {
    let expected = width as usize * height as usize;
    if len != expected {
        return Err(Error::InvalidParameter(format!(
            "{what} {width}x{height} needs {expected} values, got {len}"
        )));
    }
    Ok(())
}

fn check_same(a: usize, b: usize) -> Result<()> {
    if a != b {
        return Err(Error::InvalidParameter(format!(
            "VSD images must have one size, got {a} and {b} pixels"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// fx = fy = 1000 with the principal point in the middle of a 4×4 image: every pixel's ray
    /// is within 0.0023 % of the optical axis, so distances equal depths to 0.003 mm and no
    /// pixel below is near a threshold.
    const K: Intrinsics = Intrinsics {
        fx: 1000.0,
        fy: 1000.0,
        cx: 1.5,
        cy: 1.5,
    };

    #[rustfmt::skip]
    const TEST: [f32; 16] = [
        1000.0, 1000.0, 1000.0, 1000.0,
        1000.0, 1000.0, 1000.0, 1000.0,
         950.0,  950.0, 1000.0, 1000.0,
           0.0,    0.0, 1000.0, 1000.0,
    ];
    #[rustfmt::skip]
    const GT: [f32; 16] = [
        0.0,    0.0,    0.0, 0.0,
        0.0, 1000.0, 1000.0, 0.0,
        0.0, 1000.0, 1000.0, 0.0,
        0.0, 1000.0, 1000.0, 0.0,
    ];
    #[rustfmt::skip]
    const EST: [f32; 16] = [
        0.0, 0.0,    0.0,    0.0,
        0.0, 0.0, 1005.0, 1005.0,
        0.0, 0.0, 1030.0, 1010.0,
        0.0, 0.0, 1010.0, 1010.0,
    ];

    fn errors(taus: &[f32], mode: VisibilityMode) -> Vec<f32> {
        vsd(&TEST, &GT, &EST, 4, 4, &K, 15.0, taus, mode, CostType::Step).unwrap()
    }

    #[test]
    fn distance_map_is_the_distance_to_the_camera_centre() {
        let k = Intrinsics {
            fx: 1.0,
            fy: 1.0,
            cx: 0.0,
            cy: 0.0,
        };
        let d = depth_to_distance(&[2.0, 2.0, 0.0, 2.0], 2, 2, &k).unwrap();
        // Pixel (u, v) looks along (u, v, 1): at z = 2 the point is 2·|(u, v, 1)| away.
        assert_eq!(d[0], 2.0);
        assert!((d[1] - 2.0 * 2f32.sqrt()).abs() < 1e-6);
        assert_eq!(d[2], 0.0);
        assert!((d[3] - 2.0 * 3f32.sqrt()).abs() < 1e-6);
    }

    /// Pixels as (row, column). BOP 2019 rule, δ = 15:
    /// - visible at the true pose: (1,1) (1,2) (2,2) (3,2) lie on the test surface, (3,1) has no
    ///   test depth so counts as visible; (2,1) is 50 mm behind the test surface: occluded.
    ///   5 pixels.
    /// - visible at the estimate: (1,2) (1,3) (2,3) (3,2) (3,3) are 5–10 mm behind the test
    ///   surface; (2,2) is 30 mm behind it but visible at the true pose, so it counts. 6 pixels.
    /// - intersection (1,2) (2,2) (3,2), union 5 + 6 − 3 = 8.
    /// - differences on the intersection: 5, 30, 10 mm.
    ///
    /// τ = 20: one costly pixel → (1 + 8 − 3) / 8 = 0.75; τ = 40: none → 5/8 = 0.625;
    /// τ = 8: two → 7/8 = 0.875.
    #[test]
    fn hand_computed_bop19() {
        let e = errors(&[20.0, 40.0, 8.0], VisibilityMode::Bop19);
        assert!((e[0] - 0.75).abs() < 1e-6, "{e:?}");
        assert!((e[1] - 0.625).abs() < 1e-6, "{e:?}");
        assert!((e[2] - 0.875).abs() < 1e-6, "{e:?}");
    }

    /// BOP 2018 rule: a pixel without test depth is never visible, so (3,1) drops out of the
    /// true pose's mask (4 pixels); the estimate's mask stays 6, the intersection 3, the union
    /// 7; τ = 20 → (1 + 7 − 3) / 7 = 5/7.
    #[test]
    fn hand_computed_bop18() {
        let e = errors(&[20.0], VisibilityMode::Bop18);
        assert!((e[0] - 5.0 / 7.0).abs() < 1e-6, "{e:?}");
        let test = depth_to_distance(&TEST, 4, 4, &K).unwrap();
        let gt = depth_to_distance(&GT, 4, 4, &K).unwrap();
        let est = depth_to_distance(&EST, 4, 4, &K).unwrap();
        let visib_gt = visibility_mask(&test, &gt, 15.0, VisibilityMode::Bop18).unwrap();
        let visib_est =
            visibility_mask_est(&test, &est, &visib_gt, 15.0, VisibilityMode::Bop18).unwrap();
        let pixels = |m: &[bool]| -> Vec<usize> { (0..16).filter(|&i| m[i]).collect() };
        assert_eq!(pixels(&visib_gt), vec![5, 6, 10, 14]);
        assert_eq!(pixels(&visib_est), vec![6, 7, 10, 11, 14, 15]);
    }

    #[test]
    fn identical_renderings_cost_nothing_and_empty_ones_everything() {
        let e = vsd(
            &TEST,
            &GT,
            &GT,
            4,
            4,
            &K,
            15.0,
            &[1.0, 20.0],
            VisibilityMode::Bop19,
            CostType::Step,
        )
        .unwrap();
        assert_eq!(e, vec![0.0, 0.0]);
        let empty = [0.0f32; 16];
        let e = vsd(
            &TEST,
            &empty,
            &empty,
            4,
            4,
            &K,
            15.0,
            &[20.0],
            VisibilityMode::Bop19,
            CostType::Step,
        )
        .unwrap();
        assert_eq!(e, vec![1.0]);
    }

    #[test]
    fn truncated_linear_cost() {
        // Differences 5, 30, 10 with τ = 20 cost 0.25 + 1 + 0.5; plus 5 outside: 6.75 / 8.
        let e = vsd(
            &TEST,
            &GT,
            &EST,
            4,
            4,
            &K,
            15.0,
            &[20.0],
            VisibilityMode::Bop19,
            CostType::TruncatedLinear,
        )
        .unwrap();
        assert!((e[0] - 6.75 / 8.0).abs() < 1e-5, "{e:?}");
    }

    #[test]
    fn refuses_mismatched_sizes_and_bad_tau() {
        assert!(vsd(
            &TEST,
            &GT[..15],
            &EST,
            4,
            4,
            &K,
            15.0,
            &[20.0],
            VisibilityMode::Bop19,
            CostType::Step
        )
        .is_err());
        assert!(vsd(
            &TEST,
            &GT,
            &EST,
            4,
            4,
            &K,
            15.0,
            &[0.0],
            VisibilityMode::Bop19,
            CostType::Step
        )
        .is_err());
        assert!(vsd_errors(
            &[1.0],
            &[1.0, 2.0],
            &[1.0],
            15.0,
            &[20.0],
            VisibilityMode::Bop19,
            CostType::Step
        )
        .is_err());
    }
}
