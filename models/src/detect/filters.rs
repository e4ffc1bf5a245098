//! The two filters that discard ambiguous cases such as planes and partial matches (METHOD.md
//! §3.4).
//!
//! - **Non-consistent points**: a pose that fits part of the scene but puts model surface where
//!   the sensor sees through it, or whose visible surface is mostly unsupported, is dropped.
//! - **Silhouette vs. scene edges**: the outline of the model rendered at the pose must lie on
//!   depth discontinuities of the scene at a sufficient rate. A model slid along a table top
//!   fits the plane well but its outline crosses no edge.

use nalgebra::Point3;

use crate::detect::rescoring::Fit;
use crate::detect::scene::SceneImage;
use crate::geometry::mesh::Mesh;
use crate::geometry::render::{Renderer, Roi};
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
    /// Drop a pose when fewer than this fraction of its visible silhouette pixels match (out
    /// of at least the re-scoring's `min_visible_outline` of the whole outline). Measured: a
    /// generated part laid flush in the table top scores 0.40, its true pose 1.0; on
    /// synth-lmo-dev, 0.5 leaves the recall where 0.3 had it (0.926).
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

/// Scene depth edges, dilated by the match radius: `near_edge[v * width + u]` says whether a
/// depth discontinuity lies within `edge_radius_px` of the pixel. Computed once per frame.
pub struct EdgeMap {
    pub width: u32,
    pub height: u32,
    pub near_edge: Vec<bool>,
    /// The depth-jump rule and outline probe the map was made with.
    jump_mm: f32,
    jump_fraction: f32,
    probe_px: u32,
    max_outline_px: u32,
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
            jump_mm: params.edge_jump_mm,
            jump_fraction: params.edge_jump_fraction,
            probe_px: params.contour_probe_px,
            max_outline_px: params.max_outline_px,
        }
    }
}

/// How the rendered outline of a pose meets the scene's depth edges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OutlineCounts {
    /// Outline pixels in the image.
    pub total: u32,
    /// Outline pixels not hidden behind the scene (the scene is not well in front) where the
    /// scene just outside lies well behind, so that an edge should be seen.
    pub visible: u32,
    /// Visible outline pixels with a scene depth edge near them.
    pub matched: u32,
}

impl OutlineCounts {
    /// `matched / visible`: the fraction of the visible outline on scene edges.
    pub fn fraction(&self) -> Option<f32> {
        (self.visible > 0).then(|| self.matched as f32 / self.visible as f32)
    }

    /// Like [`fraction`](Self::fraction), but a pose whose outline is mostly hidden is not
    /// judged on the little that shows: the denominator is at least `min_visible` of the whole
    /// outline. A model placed behind the scene with one short piece of outline on an edge
    /// would otherwise score as well as a pose whose whole outline matches.
    pub fn fraction_of_at_least(&self, min_visible: f32) -> Option<f32> {
        let denominator = (self.visible as f32).max(min_visible * self.total as f32);
        (denominator > 0.0).then(|| self.matched as f32 / denominator)
    }
}

/// The outline of `mesh` rendered at `pose` against the scene's depth edges: the fraction of
/// the outline's visible pixels that lie near a scene edge, out of at least `min_visible` of the
/// whole outline ([`OutlineCounts::fraction_of_at_least`]; `None` when no outline pixel is
/// visible, e.g. the pose is outside the view).
///
/// `sphere` is the mesh's bounding sphere (model coordinates) that limits rendering to where
/// the mesh can appear; `occlusion_tolerance_mm` decides when the scene is in front of the
/// model (an occluded outline pixel says nothing). The floor matters for a model laid flush in
/// a plane: where its outline meets the plane at the same depth no edge is expected, so few
/// outline pixels count as visible, and a handful of them on an edge must not read as agreement.
#[allow(clippy::too_many_arguments)]
pub fn silhouette_fraction(
    renderer: &mut Renderer,
    mesh: &Mesh,
    sphere: &(Point3<f32>, f32),
    pose: &Pose,
    scene: &SceneImage,
    edges: &EdgeMap,
    occlusion_tolerance_mm: f32,
    min_visible: f32,
) -> Option<f32> {
    outline_counts(
        renderer,
        mesh,
        sphere,
        pose,
        scene,
        edges,
        occlusion_tolerance_mm,
    )?
    .fraction_of_at_least(min_visible)
}

/// The counts behind [`silhouette_fraction`]; `None` when the mesh is out of view.
pub fn outline_counts(
    renderer: &mut Renderer,
    mesh: &Mesh,
    sphere: &(Point3<f32>, f32),
    pose: &Pose,
    scene: &SceneImage,
    edges: &EdgeMap,
    occlusion_tolerance_mm: f32,
) -> Option<OutlineCounts> {
    let centre = pose * sphere.0;
    let full = Roi::around_sphere(
        &centre,
        sphere.1,
        &scene.intrinsics,
        scene.width,
        scene.height,
    )?;
    // Full-resolution pixels per outline pixel along each axis.
    let scale = match edges.max_outline_px {
        0 => 1,
        max => full.width.max(full.height).div_ceil(max).max(1),
    };
    let (intrinsics, roi) = if scale == 1 {
        (scene.intrinsics, full)
    } else {
        let coarse = scene.intrinsics.coarser(scale);
        let roi = Roi::around_sphere(
            &centre,
            sphere.1,
            &coarse,
            scene.width.div_ceil(scale),
            scene.height.div_ceil(scale),
        )?;
        (coarse, roi)
    };
    renderer.render_into(mesh, pose, &intrinsics, roi).ok()?;
    let depth = renderer.depth_mm();
    let (w, h) = (roi.width as i64, roi.height as i64);
    let at = |x: i64, y: i64| -> f32 {
        if x < 0 || y < 0 || x >= w || y >= h {
            0.0
        } else {
            depth[(y * w + x) as usize]
        }
    };
    // Where the image ends the object may go on: a rendered region cut by the image's border
    // has no outline there, and the cut is neither on nor off an edge.
    let (image_w, image_h) = (
        scene.width.div_ceil(scale) as i64,
        scene.height.div_ceil(scale) as i64,
    );
    let filled = |x: i64, y: i64| -> bool {
        let (gx, gy) = (x + roi.u0 as i64, y + roi.v0 as i64);
        gx < 0 || gy < 0 || gx >= image_w || gy >= image_h || at(x, y) > 0.0
    };
    let (s, half) = (scale as i64, (scale as i64 - 1) / 2);
    let (last_u, last_v) = (scene.width as i64 - 1, scene.height as i64 - 1);
    let mut counts = OutlineCounts::default();
    for y in 0..h {
        for x in 0..w {
            let z = at(x, y);
            if z <= 0.0 {
                continue;
            }
            if filled(x + 1, y) && filled(x - 1, y) && filled(x, y + 1) && filled(x, y - 1) {
                continue;
            }
            counts.total += 1;
            // The full-resolution pixel under this one's centre.
            let u = ((x + roi.u0 as i64) * s + half).min(last_u);
            let v = ((y + roi.v0 as i64) * s + half).min(last_v);
            if let Some(zs) = scene.depth(u, v) {
                if zs < z - occlusion_tolerance_mm {
                    continue;
                }
            }
            if edges.probe_px > 0 {
                // Look outwards (away from the rendered region) for background behind.
                let r = edges.probe_px as i64;
                let jump = edges.jump_mm.max(edges.jump_fraction * z);
                let mut expected = false;
                for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    if filled(x + dx, y + dy) {
                        continue;
                    }
                    match scene.depth(u + dx * r, v + dy * r) {
                        Some(zs) if zs <= z + jump => {}
                        _ => expected = true,
                    }
                }
                if !expected {
                    continue;
                }
            }
            counts.visible += 1;
            if edges.near_edge[(v * edges.width as i64 + u) as usize] {
                counts.matched += 1;
            }
        }
    }
    Some(counts)
}

/// A coarser copy of `mesh` for silhouettes: vertices merged on a grid of `cell_mm` (each
/// cell's vertices replaced by their mean), faces that collapse dropped. Scanned models carry
/// tens of thousands of triangles of a millimetre or so, most smaller than a pixel at working
/// distance; merging them keeps the outline within a cell and makes rendering several times
/// cheaper. The detector's cell is 0.04 D (see
/// [`crate::detect::rescoring::RescoringParams::silhouette_mesh_cell_fraction`]): 4–10 mm for the LM-O
/// objects, 2–6 pixels at 1 m.
pub fn simplified_mesh(mesh: &Mesh, cell_mm: f32) -> Mesh {
    if cell_mm.is_nan() || cell_mm <= 0.0 {
        return mesh.clone();
    }
    let inv = 1.0 / cell_mm;
    let mut cell_of: crate::geometry::grid::CellMap<u32> = Default::default();
    let mut sums: Vec<(nalgebra::Vector3<f32>, u32)> = Vec::new();
    let remap: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            let key = crate::geometry::grid::cell_of(p, inv);
            let id = *cell_of.entry(key).or_insert_with(|| {
                sums.push((nalgebra::Vector3::zeros(), 0));
                (sums.len() - 1) as u32
            });
            sums[id as usize].0 += p.coords;
            sums[id as usize].1 += 1;
            id
        })
        .collect();
    let positions = sums
        .iter()
        .map(|(s, n)| Point3::from(s / *n as f32))
        .collect();
    let faces = mesh
        .faces
        .iter()
        .map(|f| f.map(|i| remap[i as usize]))
        .filter(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2])
        .collect();
    Mesh {
        positions,
        normals: Vec::new(),
        faces,
    }
}
