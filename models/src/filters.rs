//! The two filters that discard ambiguous cases such as planes and partial matches (METHOD.md
//! §3.4).
//!
//! - **Non-consistent points**: a pose that fits part of the scene but puts model surface where
//!   the sensor sees through it, or whose visible surface is mostly unsupported, is dropped.
//! - **Silhouette vs. scene edges**: the outline of the model rendered at the pose must lie on
//!   depth discontinuities of the scene at a sufficient rate. A model slid along a table top
//!   fits the plane well but its outline crosses no edge.

use nalgebra::Point3;

use crate::mesh::Mesh;
use crate::render::{Renderer, Roi};
use crate::rescoring::Fit;
use crate::scene::SceneImage;
use crate::Pose;

/// Parameters of the two filters. Defaults were measured on generated scenes and the LM-O
/// frame (see the README's results).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterParams {
    /// Drop a pose when more than this fraction of its measured facing points have the scene
    /// well behind them (the sensor sees through the model).
    pub max_see_through_fraction: f32,
    /// Drop a pose when fewer than this fraction of its visible (measured, not occluded) points
    /// are inliers.
    pub min_support_fraction: f32,
    /// A scene pixel is a depth edge when a neighbour within one pixel has no depth or differs
    /// by more than `edge_jump_mm` or `edge_jump_fraction` of the depth, whichever is larger
    /// (depth noise and quantisation of structured-light sensors grow with distance).
    pub edge_jump_mm: f32,
    pub edge_jump_fraction: f32,
    /// A silhouette pixel matches when a scene edge lies within this many pixels.
    pub edge_radius_px: u32,
    /// Drop a pose when fewer than this fraction of its unoccluded silhouette pixels match.
    pub min_silhouette_fraction: f32,
    /// The filters run on the refined poses in score order until enough pass; at most this
    /// many are examined per object.
    pub max_candidates: usize,
}

impl Default for FilterParams {
    fn default() -> Self {
        Self {
            max_see_through_fraction: 0.2,
            min_support_fraction: 0.5,
            edge_jump_mm: 10.0,
            edge_jump_fraction: 0.02,
            edge_radius_px: 2,
            min_silhouette_fraction: 0.3,
            max_candidates: 50,
        }
    }
}

/// The non-consistent-points check on a fit measured at the final tolerance.
pub fn is_consistent(fit: &Fit, params: &FilterParams) -> bool {
    if fit.measured == 0 || fit.visible() == 0 {
        return false;
    }
    let see_through = fit.see_through as f32 / fit.measured as f32;
    let support = fit.inliers as f32 / fit.visible() as f32;
    see_through <= params.max_see_through_fraction && support >= params.min_support_fraction
}

/// Scene depth edges, dilated by the match radius: `near_edge[v * width + u]` says whether a
/// depth discontinuity lies within `edge_radius_px` of the pixel. Computed once per frame.
pub struct EdgeMap {
    pub width: u32,
    pub height: u32,
    pub near_edge: Vec<bool>,
}

impl EdgeMap {
    pub fn new(scene: &SceneImage, params: &FilterParams) -> Self {
        let (w, h) = (scene.width as i64, scene.height as i64);
        let mut edge = vec![false; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let Some(z) = scene.depth(u, v) else { continue };
                let jump = params.edge_jump_mm.max(params.edge_jump_fraction * z);
                let mut is_edge = false;
                for (du, dv) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    match scene.depth(u + du, v + dv) {
                        Some(zn) if (zn - z).abs() <= jump => {}
                        _ => is_edge = true,
                    }
                }
                edge[(v * w + u) as usize] = is_edge;
            }
        }
        // Dilate with a square of radius r: rows, then columns.
        let r = params.edge_radius_px as i64;
        let mut rows = vec![false; edge.len()];
        for v in 0..h {
            for u in 0..w {
                rows[(v * w + u) as usize] = (u.saturating_sub(r).max(0)..=(u + r).min(w - 1))
                    .any(|x| edge[(v * w + x) as usize]);
            }
        }
        let mut near_edge = vec![false; edge.len()];
        for v in 0..h {
            for u in 0..w {
                near_edge[(v * w + u) as usize] =
                    ((v - r).max(0)..=(v + r).min(h - 1)).any(|y| rows[(y * w + u) as usize]);
            }
        }
        Self {
            width: scene.width,
            height: scene.height,
            near_edge,
        }
    }
}

/// The outline of `mesh` rendered at `pose` against the scene's depth edges: the fraction of
/// the outline's unoccluded pixels that lie near a scene edge (`None` when no outline pixel is
/// visible, e.g. the pose is outside the view).
///
/// `sphere` is the mesh's bounding sphere (model coordinates) that limits rendering to where
/// the mesh can appear; `occlusion_tolerance_mm` decides when the scene is in front of the
/// model (an occluded outline pixel says nothing).
pub fn silhouette_fraction(
    renderer: &mut Renderer,
    mesh: &Mesh,
    sphere: &(Point3<f32>, f32),
    pose: &Pose,
    scene: &SceneImage,
    edges: &EdgeMap,
    occlusion_tolerance_mm: f32,
) -> Option<f32> {
    let roi = Roi::around_sphere(
        &(pose * sphere.0),
        sphere.1,
        &scene.intrinsics,
        scene.width,
        scene.height,
    )?;
    renderer
        .render_into(mesh, pose, &scene.intrinsics, roi)
        .ok()?;
    let depth = renderer.depth_mm();
    let (w, h) = (roi.width as i64, roi.height as i64);
    let at = |x: i64, y: i64| -> f32 {
        if x < 0 || y < 0 || x >= w || y >= h {
            0.0
        } else {
            depth[(y * w + x) as usize]
        }
    };
    let (mut outline, mut matched) = (0u32, 0u32);
    for y in 0..h {
        for x in 0..w {
            let z = at(x, y);
            if z <= 0.0 {
                continue;
            }
            if at(x + 1, y) > 0.0 && at(x - 1, y) > 0.0 && at(x, y + 1) > 0.0 && at(x, y - 1) > 0.0
            {
                continue;
            }
            let (u, v) = (x + roi.u0 as i64, y + roi.v0 as i64);
            if let Some(zs) = scene.depth(u, v) {
                if zs < z - occlusion_tolerance_mm {
                    continue;
                }
            }
            outline += 1;
            if edges.near_edge[(v * edges.width as i64 + u) as usize] {
                matched += 1;
            }
        }
    }
    (outline > 0).then(|| matched as f32 / outline as f32)
}
