//! `ppf generate`: writes the generated scene that `ppf demo` shows as a dataset in the BOP
//! layout, so that tools outside this process read it as they read any BOP data: a daemon
//! builds the parts' models from `models/`, `ppf replay` and the Python examples publish its
//! depth, `ppf eval` scores against its ground truth.
//!
//! ```text
//! out/
//!   camera.json
//!   models/obj_000001.ply …       the generated parts (ASCII PLY with normals)
//!   test/000000/
//!     scene_camera.json  scene_gt.json  depth/000000.png   (16-bit, 1 mm per unit)
//! ```

use std::path::{Path, PathBuf};

use clap::Args;
use ppfd_models::synthetic::scene::SyntheticScene;
use serde_json::json;

use crate::demo::parts_scene;

#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// Folder to write the dataset into (created; files of the same names are replaced).
    pub out: PathBuf,
    /// Seed of the generated scene (`ppf demo --seed`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Render the scene without sensor noise.
    #[arg(long)]
    pub no_noise: bool,
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), String> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    std::fs::write(path, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// The depth image as BOP stores it: a 16-bit grayscale PNG.
fn depth_png(width: u32, height: u32, depth: &[u16]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let bytes: Vec<u8> = depth.iter().flat_map(|d| d.to_be_bytes()).collect();
    encoder
        .write_header()
        .and_then(|mut w| w.write_image_data(&bytes))
        .map_err(|e| format!("cannot encode the depth PNG: {e}"))?;
    Ok(out)
}

/// Writes `scene` and the meshes of its objects into `out` in the BOP layout.
fn write_dataset(
    out: &Path,
    meshes: &[(u32, &ppfd_models::geometry::mesh::Mesh)],
    scene: &SyntheticScene,
) -> Result<(), String> {
    let f = &scene.frame;
    let k = f.intrinsics;
    for (id, mesh) in meshes {
        let path = out.join("models").join(format!("obj_{id:06}.ply"));
        write(&path, mesh.to_ply_ascii().as_bytes())?;
    }
    let camera = json!({
        "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
        "width": f.width, "height": f.height, "depth_scale": f.depth_scale_mm,
    });
    let scene_camera = json!({"0": {
        "cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        "depth_scale": f.depth_scale_mm,
    }});
    let truth: Vec<_> = scene
        .ground_truth
        .iter()
        .map(|(id, pose)| {
            let r = pose.rotation.to_rotation_matrix();
            let r: Vec<f32> = (0..3)
                .flat_map(|row| (0..3).map(move |col| r[(row, col)]))
                .collect();
            let t = pose.translation.vector;
            json!({"obj_id": id, "cam_R_m2c": r, "cam_t_m2c": [t.x, t.y, t.z]})
        })
        .collect();
    let scene_dir = out.join("test").join("000000");
    let pretty = |v: &serde_json::Value| serde_json::to_vec_pretty(v).expect("JSON values print");
    write(&out.join("camera.json"), &pretty(&camera))?;
    write(&scene_dir.join("scene_camera.json"), &pretty(&scene_camera))?;
    write(
        &scene_dir.join("scene_gt.json"),
        &pretty(&json!({"0": truth})),
    )?;
    write(
        &scene_dir.join("depth").join("000000.png"),
        &depth_png(f.width, f.height, &f.depth)?,
    )
}

pub fn run(args: GenerateArgs) -> Result<(), String> {
    let (meshes, scene) = parts_scene(args.seed, args.no_noise)?;
    let meshes: Vec<_> = meshes.iter().map(|(p, m)| (p.object_id(), m)).collect();
    write_dataset(&args.out, &meshes, &scene)?;
    println!(
        "wrote the generated scene of seed {} ({} objects) as a BOP dataset in {}",
        args.seed,
        scene.ground_truth.len(),
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ppfd_bop::dataset::BopDataset;
    use ppfd_models::geometry::mesh::Mesh;

    /// What `ppf generate` writes reads back through the BOP reader as the scene it generated:
    /// the same depth values, intrinsics, truth and meshes.
    #[test]
    fn the_written_dataset_reads_back_as_the_generated_scene() {
        let dir = crate::common::ScratchDir::create("ppf-generate-test").unwrap();
        run(GenerateArgs {
            out: dir.path().to_owned(),
            seed: 3,
            no_noise: false,
        })
        .unwrap();
        let (meshes, scene) = parts_scene(3, false).unwrap();
        let data = BopDataset::open(dir.path()).unwrap();
        assert_eq!(data.scene_ids(), [0]);
        let frame = data.depth_frame(0, 0).unwrap();
        assert_eq!(
            (frame.width, frame.height),
            (scene.frame.width, scene.frame.height)
        );
        assert_eq!(frame.intrinsics, scene.frame.intrinsics);
        assert_eq!(frame.depth_scale_mm, scene.frame.depth_scale_mm);
        assert!(frame.depth == scene.frame.depth, "depth values differ");
        let truth = data.ground_truth(0, 0).unwrap();
        assert_eq!(truth.len(), scene.ground_truth.len());
        for (read, (id, pose)) in truth.iter().zip(&scene.ground_truth) {
            assert_eq!(read.obj_id, *id);
            let dt = (read.pose.translation.vector - pose.translation.vector).norm();
            let dr = read.pose.rotation.angle_to(&pose.rotation).to_degrees();
            assert!(
                dt < 1e-3 && dr < 1e-2,
                "object {id}: {dt} mm, {dr} deg apart"
            );
        }
        let ids: Vec<u32> = meshes.iter().map(|(p, _)| p.object_id()).collect();
        assert_eq!(data.object_ids(), ids);
        for (part, mesh) in &meshes {
            let read = Mesh::from_ply_file(data.model_path(part.object_id()).unwrap()).unwrap();
            assert_eq!(read.positions, mesh.positions, "{}", part.name());
            assert_eq!(read.faces, mesh.faces, "{}", part.name());
        }
    }
}
