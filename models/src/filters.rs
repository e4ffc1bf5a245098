//! The two filters that discard ambiguous cases such as planes and partial matches (METHOD.md
//! §3.4).
//!
//! - **Non-consistent points**: a pose that fits part of the scene but puts model surface where
//!   the sensor sees through it, or whose visible surface is mostly unsupported, is dropped.
//! - **Silhouette vs. scene edges**: the outline of the model rendered at the pose must lie on
//!   depth discontinuities of the scene at a sufficient rate. A model slid along a table top
//!   fits the plane well but its outline crosses no edge.

use crate::rescoring::Fit;
use crate::scene::SceneImage;

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
    /// by more than this, mm.
    pub edge_jump_mm: f32,
    /// A silhouette pixel matches when a scene edge lies within this many pixels.
    pub edge_radius_px: u32,
    /// Drop a pose when fewer than this fraction of its unoccluded silhouette pixels match.
    pub min_silhouette_fraction: f32,
}

impl Default for FilterParams {
    fn default() -> Self {
        Self {
            max_see_through_fraction: 0.2,
            min_support_fraction: 0.5,
            edge_jump_mm: 10.0,
            edge_radius_px: 2,
            min_silhouette_fraction: 0.3,
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
                let mut is_edge = false;
                for (du, dv) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    match scene.depth(u + du, v + dv) {
                        Some(zn) if (zn - z).abs() <= params.edge_jump_mm => {}
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
