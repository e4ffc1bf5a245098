//! What scoring needs that a dataset may lack: the visibility of each annotated instance
//! (`scene_gt_info.json`) and each object's metadata (`models_info.json`), computed from the
//! depth images and the meshes. BOP datasets ship both files; a capture of one's own, annotated
//! with `scene_gt.json` alone, does not.
//!
//! - [`estimate_gt_info`] follows BOP's `calc_gt_info`: each instance is rendered alone at its
//!   pose, on a canvas three times the image's size so that its whole silhouette counts even
//!   where the image cuts it; a pixel of it is visible where the test depth is missing or lies
//!   no more than δ = 15 mm in front of the rendered surface (the 2019 visibility rule, on
//!   distances from the camera centre). The visible fraction is visible pixels over the whole
//!   silhouette's.
//! - [`model_info_from_mesh`]: diameter and bounding box of the mesh's vertices, and no
//!   symmetries (none can be known from a mesh alone, so a symmetric object's poses turned by
//!   a symmetry count as wrong under MSSD and MSPD; VSD does not depend on it).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use nalgebra::Point3;

use crate::dataset::{BopDataset, GtInfo, ModelInfo};
use crate::eval::vsd::{depth_to_distance, visibility_mask, VisibilityMode};
use ppfd_models::geometry::camera::Intrinsics;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::geometry::render::{Renderer, Roi};
use ppfd_models::model::sampling::diameter;
use ppfd_models::Pose;

use crate::Result;

/// δ of BOP's `calc_gt_info`, mm.
pub const VISIBILITY_TOLERANCE_MM: f32 = 15.0;

/// The visibility of each of `instances` (a mesh and its model → camera pose) against one
/// depth image (`width × height`, mm, 0 = no measurement), in their order.
pub fn estimate_gt_info(
    depth_mm: &[f32],
    width: u32,
    height: u32,
    intrinsics: &Intrinsics,
    instances: &[(&Mesh, Pose)],
) -> Result<Vec<GtInfo>> {
    let dist_test = depth_to_distance(depth_mm, width, height, intrinsics)?;
    // The large canvas: the image in its middle.
    let (w, h) = (width as usize, height as usize);
    let large = Intrinsics {
        cx: intrinsics.cx + width as f32,
        cy: intrinsics.cy + height as f32,
        ..*intrinsics
    };
    let mut renderer = Renderer::new();
    let mut out = Vec::with_capacity(instances.len());
    for (mesh, pose) in instances {
        renderer.render_into(mesh, pose, &large, Roi::full(3 * width, 3 * height))?;
        let rendered = renderer.depth_mm();
        let px_count_all = rendered.iter().filter(|&&z| z > 0.0).count() as u32;
        let mut depth_gt = vec![0.0f32; w * h];
        for v in 0..h {
            let row = (v + h) * 3 * w + w;
            depth_gt[v * w..(v + 1) * w].copy_from_slice(&rendered[row..row + w]);
        }
        let dist_gt = depth_to_distance(&depth_gt, width, height, intrinsics)?;
        let visible = visibility_mask(
            &dist_test,
            &dist_gt,
            VISIBILITY_TOLERANCE_MM,
            VisibilityMode::Bop19,
        )?;
        let px_count_valid = depth_gt
            .iter()
            .zip(depth_mm)
            .filter(|(&g, &t)| g > 0.0 && t > 0.0)
            .count() as u32;
        let px_count_visib = visible.iter().filter(|&&v| v).count() as u32;
        out.push(GtInfo {
            visib_fract: if px_count_all > 0 {
                px_count_visib as f32 / px_count_all as f32
            } else {
                0.0
            },
            px_count_all,
            px_count_valid,
            px_count_visib,
            // Of the part in the image (BOP's box also spans what the image cuts off).
            bbox_obj: bbox(width, height, |i| depth_gt[i] > 0.0),
            bbox_visib: bbox(width, height, |i| visible[i]),
        });
    }
    Ok(out)
}

/// `[x, y, width, height]` of the pixels where `set` holds in a `width × height` image
/// (row-major), −1s when it holds nowhere.
fn bbox(width: u32, height: u32, set: impl Fn(usize) -> bool) -> [i32; 4] {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for v in 0..height {
        for u in 0..width {
            if set((v * width + u) as usize) {
                (x0, y0) = (x0.min(u), y0.min(v));
                (x1, y1) = (x1.max(u), y1.max(v));
            }
        }
    }
    if x0 == u32::MAX {
        return [-1; 4];
    }
    [
        x0 as i32,
        y0 as i32,
        (x1 - x0 + 1) as i32,
        (y1 - y0 + 1) as i32,
    ]
}

/// An object's metadata from its mesh alone: the vertices' diameter and bounding box, no
/// symmetries.
pub fn model_info_from_mesh(mesh: &Mesh) -> ModelInfo {
    let (mut min, mut max) = (
        Point3::from([f32::INFINITY; 3]),
        Point3::from([f32::NEG_INFINITY; 3]),
    );
    for p in &mesh.positions {
        min = min.inf(p);
        max = max.sup(p);
    }
    if mesh.positions.is_empty() {
        (min, max) = (Point3::origin(), Point3::origin());
    }
    ModelInfo {
        diameter_mm: diameter(&mesh.positions),
        min_mm: min,
        size_mm: max - min,
        symmetries_discrete: Vec::new(),
        symmetries_continuous: Vec::new(),
    }
}

/// Meshes of a dataset's objects, each read once (`models_eval/`, else `models/`), shared
/// between threads.
#[derive(Debug, Default)]
pub struct MeshCache {
    meshes: Mutex<BTreeMap<u32, Arc<Mesh>>>,
}

impl MeshCache {
    /// The mesh of object `obj_id`.
    pub fn get(&self, dataset: &BopDataset, obj_id: u32) -> Result<Arc<Mesh>> {
        if let Some(m) = self.lock().get(&obj_id) {
            return Ok(m.clone());
        }
        let path = dataset
            .eval_model_path(obj_id)
            .or_else(|_| dataset.model_path(obj_id))?;
        let mesh = Arc::new(Mesh::from_ply_file(&path)?);
        Ok(self.lock().entry(obj_id).or_insert(mesh).clone())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<u32, Arc<Mesh>>> {
        // A panic elsewhere while holding the lock leaves the map as it was: still usable.
        self.meshes.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The visibility of one image's annotated instances, in the order of its ground truth: the
/// scene's `scene_gt_info.json` when it has one, else [`estimate_gt_info`] with the image's
/// depth and the objects' meshes.
pub fn image_gt_info(
    dataset: &BopDataset,
    scene_id: u32,
    im_id: u32,
    meshes: &MeshCache,
) -> Result<Vec<GtInfo>> {
    if dataset.has_ground_truth_info(scene_id) {
        return Ok(dataset.ground_truth_info(scene_id, im_id)?.to_vec());
    }
    let gt = dataset.ground_truth(scene_id, im_id)?;
    let frame = dataset.depth_frame(scene_id, im_id)?;
    let depth_mm: Vec<f32> = frame
        .depth
        .iter()
        .map(|&d| d as f32 * frame.depth_scale_mm)
        .collect();
    let owned: Vec<Arc<Mesh>> = gt
        .iter()
        .map(|g| meshes.get(dataset, g.obj_id))
        .collect::<Result<_>>()?;
    let instances: Vec<(&Mesh, Pose)> = owned.iter().zip(gt).map(|(m, g)| (&**m, g.pose)).collect();
    estimate_gt_info(
        &depth_mm,
        frame.width,
        frame.height,
        &frame.intrinsics,
        &instances,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use ppfd_models::geometry::render::render_depth;
    use ppfd_models::synthetic::parts::box_mesh;

    const K: Intrinsics = Intrinsics {
        fx: 500.0,
        fy: 500.0,
        cx: 160.0,
        cy: 120.0,
    };

    fn at(x: f32, y: f32, z: f32) -> Pose {
        Pose::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
    }

    #[test]
    fn occluded_and_cut_off_instances_count_what_is_seen_of_their_whole_silhouette() {
        let (w, h) = (320, 240);
        let cube = box_mesh(Vector3::new(100.0, 100.0, 100.0));
        // One cube in the middle, its left half hidden by something 200 mm in front; one
        // whose centre sits on the image's right border, in full view.
        let (middle, cut) = (
            at(0.0, 0.0, 1000.0),
            at(160.0 * 1050.0 / 500.0, 0.0, 1050.0),
        );
        let a = render_depth(&cube, &middle, &K, w, h).unwrap();
        let b = render_depth(&cube, &cut, &K, w, h).unwrap();
        let mut depth: Vec<f32> = (0..(w * h) as usize)
            .map(|i| {
                let (za, zb) = (a.depth_mm[i], b.depth_mm[i]);
                match (za > 0.0, zb > 0.0) {
                    (true, true) => za.min(zb),
                    (true, false) => za,
                    (false, true) => zb,
                    (false, false) => 2000.0,
                }
            })
            .collect();
        for v in 0..h as usize {
            for u in 0..160 {
                if a.depth_mm[v * w as usize + u] > 0.0 {
                    depth[v * w as usize + u] = 800.0;
                }
            }
        }
        let info = estimate_gt_info(&depth, w, h, &K, &[(&cube, middle), (&cube, cut)]).unwrap();
        let (m, c) = (info[0], info[1]);
        assert!((m.visib_fract - 0.5).abs() < 0.02, "{m:?}");
        assert_eq!(m.px_count_valid, m.px_count_all, "{m:?}");
        assert!((c.visib_fract - 0.5).abs() < 0.03, "{c:?}");
        // The cut-off cube's whole silhouette counts, of which the image holds about half.
        assert!(c.px_count_all > m.px_count_all * 8 / 10, "{c:?} {m:?}");
        assert_eq!(c.px_count_visib, c.px_count_valid, "{c:?}");
        assert_eq!(c.bbox_obj[0] + c.bbox_obj[2], w as i32, "{c:?}");
        // Depth missing where the first cube is seen: visible by the 2019 rule.
        let holes: Vec<f32> = depth
            .iter()
            .zip(&a.depth_mm)
            .map(|(&d, &za)| if za > 0.0 { 0.0 } else { d })
            .collect();
        let info = estimate_gt_info(&holes, w, h, &K, &[(&cube, middle)]).unwrap();
        assert!(info[0].visib_fract > 0.99, "{:?}", info[0]);
        assert_eq!(info[0].px_count_valid, 0, "{:?}", info[0]);
    }

    #[test]
    fn an_instance_behind_the_camera_or_out_of_view_is_invisible() {
        let cube = box_mesh(Vector3::new(50.0, 50.0, 50.0));
        let depth = vec![1000.0f32; 320 * 240];
        let info = estimate_gt_info(
            &depth,
            320,
            240,
            &K,
            &[
                (&cube, at(0.0, 0.0, -500.0)),
                (&cube, at(5000.0, 0.0, 1000.0)),
            ],
        )
        .unwrap();
        for i in info {
            assert_eq!((i.visib_fract, i.px_count_all), (0.0, 0), "{i:?}");
            assert_eq!(i.bbox_visib, [-1; 4]);
        }
    }

    #[test]
    fn mesh_info_has_the_box_diagonal_and_no_symmetry() {
        let info = model_info_from_mesh(&box_mesh(Vector3::new(30.0, 40.0, 120.0)));
        assert!((info.diameter_mm - 130.0).abs() < 0.5, "{info:?}");
        assert_eq!(info.size_mm, Vector3::new(30.0, 40.0, 120.0));
        assert!(info.symmetries_discrete.is_empty() && info.symmetries_continuous.is_empty());
    }

    /// Against the BOP toolkit's own figures: the LM-O frame's `scene_gt_info.json`.
    #[test]
    fn visibility_agrees_with_the_lmo_frames_own_file() {
        let Some(dir) = crate::shared_test_data("lmo") else {
            return;
        };
        let data = BopDataset::open(dir).unwrap();
        let meshes = MeshCache::default();
        let gt = data.ground_truth(2, 3).unwrap();
        let frame = data.depth_frame(2, 3).unwrap();
        let depth: Vec<f32> = frame.depth.iter().map(|&d| d as f32).collect();
        let owned: Vec<_> = gt
            .iter()
            .map(|g| meshes.get(&data, g.obj_id).unwrap())
            .collect();
        let instances: Vec<(&Mesh, Pose)> =
            owned.iter().zip(gt).map(|(m, g)| (&**m, g.pose)).collect();
        let ours = estimate_gt_info(&depth, 640, 480, &frame.intrinsics, &instances).unwrap();
        let theirs = data.ground_truth_info(2, 3).unwrap();
        assert_eq!((ours.len(), theirs.len()), (gt.len(), gt.len()));
        let mut table = String::from("obj  visib (file, ours)  px_all (file, ours)\n");
        for ((g, o), t) in gt.iter().zip(&ours).zip(theirs) {
            table += &format!(
                "{:3}  {:.3} {:.3}  {} {}\n",
                g.obj_id, t.visib_fract, o.visib_fract, t.px_count_all, o.px_count_all
            );
        }
        println!("{table}");
        for (o, t) in ours.iter().zip(theirs) {
            assert!((o.visib_fract - t.visib_fract).abs() < 0.015, "{table}");
            let ratio = o.px_count_all as f32 / t.px_count_all as f32;
            assert!((ratio - 1.0).abs() < 0.01, "{table}");
        }
    }
}
