//! The two filters that discard ambiguous cases such as planes and partial matches (METHOD.md
//! §3.4).
//!
//! - **Non-consistent points**: a pose that fits part of the scene but puts model surface where
//!   the sensor sees through it (away from depth edges, where sensors lose thin rims), or whose
//!   visible surface is mostly unsupported, is dropped.
//! - **Silhouette vs. scene edges**: the outline of the model rendered at the pose must lie on
//!   depth discontinuities of the scene at a sufficient rate. A model slid along a table top
//!   fits the plane well but its outline crosses no edge.

use rayon::prelude::*;

use crate::detect::rescoring::{judge_point, Judgement, PoseMatrix};
use crate::detect::scene::SceneImage;
use crate::detect::silhouette::{EdgeMap, Fit};
use crate::model::subsample::OrientedPoints;
use crate::Pose;

/// Parameters of the two filters. Defaults were measured on generated scenes and the LM-O
/// frame (see the README's results).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterParams {
    /// Drop a pose when more than this fraction of its measured facing points have the scene
    /// well behind them (the sensor sees through the model) away from depth edges
    /// ([`consistency_off_edges`]).
    pub max_see_through_fraction: f32,
    /// Drop a pose when fewer than this fraction of its visible (measured, not occluded) points
    /// are inliers.
    pub min_support_fraction: f32,
    /// A scene pixel is a depth edge when a neighbour within one pixel has no depth or differs
    /// by more than `edge_jump_mm` or `edge_jump_fraction` of the depth, whichever is larger
    /// (depth noise and quantisation of structured-light sensors grow with distance).
    pub edge_jump_mm: f32,
    /// The edges' depth jump as a fraction of the pixel's depth (see `edge_jump_mm`).
    pub edge_jump_fraction: f32,
    /// A silhouette pixel matches when a scene edge lies within this many pixels.
    pub edge_radius_px: u32,
    /// Drop a pose when fewer than this fraction of its visible silhouette pixels match (as
    /// [`SilhouetteFilter::fraction`](crate::detect::silhouette::SilhouetteFilter::fraction)
    /// counts them). Measured: a generated part laid flush in the table top scores 0 away from
    /// the table's border and 0.26 at it, its true pose 1.0; on synth-lmo-dev, 0.5 leaves the
    /// recall where 0.3 had it (0.926).
    pub min_silhouette_fraction: f32,
    /// An outline pixel expects a scene edge only where the scene this many pixels outside the
    /// outline lies farther than the model by a depth jump (or has no depth): where an object
    /// rests on a table, the table meets its outline at the same depth and no edge can be
    /// seen. 0 expects an edge everywhere.
    pub contour_probe_px: u32,
    /// Outlines are rendered at a coarser scale (every 2nd, 3rd … pixel along each axis) when
    /// the object would span more than this many pixels: an object near the camera covers
    /// 200 × 200 pixels and more, and re-scoring draws hundreds of outlines per object, while
    /// the outline's agreement with the edges is a fraction that a sample of it measures as
    /// well. Each coarse outline pixel is judged at the full-resolution pixel under its
    /// centre. 0 always renders at full resolution.
    pub max_outline_px: u32,
    /// The filters run on the refined poses in score order until enough pass; at most this
    /// many are examined per object.
    pub max_candidates: usize,
}

impl Default for FilterParams {
    fn default() -> Self {
        Self {
            max_see_through_fraction: 0.2,
            min_support_fraction: 0.3,
            edge_jump_mm: 10.0,
            edge_jump_fraction: 0.02,
            edge_radius_px: 2,
            min_silhouette_fraction: 0.5,
            contour_probe_px: 3,
            max_outline_px: 160,
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

/// The filter's judgement of `fit`, the fit of `surface` at `pose` ([`is_consistent`]), with a
/// point the sensor sees through counted only away from the scene's depth edges: returns
/// whether it passes and the fit as judged. Structured-light sensors lose thin parts and the
/// rims of surfaces, and the floor beyond shows through there; the right pose of a thin
/// bracket left 24 % of its points seen through on a generated Kinect-like frame, all within
/// two pixels of a depth edge, and the LM-O glue's 19 % (of which 11 of 156 points are away
/// from edges; docs/METHOD.md §3.4). A pose that floats before the scene is seen through
/// across its surface, not only along its rims. The points are counted again only when all of
/// them are too many.
pub fn consistency_off_edges(
    fit: &Fit,
    surface: &OrientedPoints,
    pose: &Pose,
    scene: &SceneImage,
    edges: &EdgeMap,
    conflict_mm: f32,
    params: &FilterParams,
) -> (bool, Fit) {
    let mut judged = *fit;
    if fit.measured > 0
        && fit.see_through as f32 > params.max_see_through_fraction * fit.measured as f32
    {
        judged.see_through = see_through_off_edges(surface, pose, scene, edges, conflict_mm);
    }
    (is_consistent(&judged, params), judged)
}

/// How many of `surface`'s points at `pose` face the camera and have the scene more than
/// `conflict_mm` behind them (seen through, as [`judge_point`] judges) at a pixel that is not
/// near a depth edge of `edges`.
pub fn see_through_off_edges(
    surface: &OrientedPoints,
    pose: &Pose,
    scene: &SceneImage,
    edges: &EdgeMap,
    conflict_mm: f32,
) -> u32 {
    let moved = PoseMatrix::new(pose);
    let mut count = 0;
    for (p, n) in surface.positions.iter().zip(&surface.normals) {
        // The see-through judgement reads only the depth: the inlier tolerance and the normal
        // angle do not enter it.
        if let Some((Judgement::SeeThrough, u, v)) =
            judge_point(&moved, p, n, scene, conflict_mm, conflict_mm, -1.0)
        {
            let at = v as usize * edges.width as usize + u as usize;
            count += u32::from(!edges.near_edge[at]);
        }
    }
    count
}

// The edge map is made by the filters' edge rule; `silhouette` measures outlines against it.
impl EdgeMap {
    /// The depth edges of `scene` by the jump rule of `params`, dilated by `edge_radius_px`.
    pub fn new(scene: &SceneImage, params: &FilterParams) -> Self {
        let (w, h) = (scene.width as i64, scene.height as i64);
        // Each pass writes one row from rows of the one before: the rows go side by side.
        let mut edge = vec![false; (w * h) as usize];
        edge.par_chunks_mut(w as usize)
            .enumerate()
            .for_each(|(v, row)| {
                let v = v as i64;
                for (u, out) in row.iter_mut().enumerate() {
                    let u = u as i64;
                    let Some(z) = scene.depth(u, v) else { continue };
                    let jump = params.edge_jump_mm.max(params.edge_jump_fraction * z);
                    let mut is_edge = false;
                    for (du, dv) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                        let (un, vn) = (u + du, v + dv);
                        // The image's border is where the view ends, not a depth edge.
                        if un < 0 || vn < 0 || un >= w || vn >= h {
                            continue;
                        }
                        match scene.depth(un, vn) {
                            Some(zn) if (zn - z).abs() <= jump => {}
                            _ => is_edge = true,
                        }
                    }
                    *out = is_edge;
                }
            });
        // Dilate with a square of radius r: rows, then columns.
        let r = params.edge_radius_px as i64;
        let mut rows = vec![false; edge.len()];
        rows.par_chunks_mut(w as usize)
            .enumerate()
            .for_each(|(v, row)| {
                let line = &edge[v * w as usize..(v + 1) * w as usize];
                for (u, out) in row.iter_mut().enumerate() {
                    let u = u as i64;
                    *out =
                        (u.saturating_sub(r).max(0)..=(u + r).min(w - 1)).any(|x| line[x as usize]);
                }
            });
        let mut near_edge = vec![false; edge.len()];
        near_edge
            .par_chunks_mut(w as usize)
            .enumerate()
            .for_each(|(v, row)| {
                let v = v as i64;
                for (u, out) in row.iter_mut().enumerate() {
                    *out =
                        ((v - r).max(0)..=(v + r).min(h - 1)).any(|y| rows[(y * w) as usize + u]);
                }
            });
        Self {
            width: scene.width,
            height: scene.height,
            near_edge,
            jump_mm: params.edge_jump_mm,
            jump_fraction: params.edge_jump_fraction,
            probe_px: params.contour_probe_px,
            max_outline_px: params.max_outline_px,
        }
    }
}
