//! `ppf generate`: writes the generated scene that `ppf demo` shows as a dataset in the BOP
//! layout, so that tools outside this process read it as they read any BOP data: a daemon
//! builds the parts' models from `models/`, `ppf replay` and the Python examples publish its
//! depth, `ppf eval` scores against its ground truth. With `--models`, a cell's own meshes
//! rest on the table instead of the generated parts, and `--clutter` adds boxes and cylinders
//! around them: a scene to try the detector on before a camera is wired.
//!
//! ```text
//! out/
//!   camera.json
//!   models/obj_000001.ply …       the meshes placed (ASCII PLY with normals)
//!          models_info.json      with --models, the source folder's entries for them, if any
//!   test/000000/
//!     scene_camera.json  scene_gt.json  depth/000000.png   (16-bit, 1 mm per unit)
//! ```

use std::path::{Path, PathBuf};

use clap::Args;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::sanity;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SyntheticScene};
use serde_json::json;

#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// Folder to write the dataset into: created, or one holding only files this run writes
    /// (an earlier run's, replaced); a folder holding anything else is refused, as a reader
    /// of the dataset would take it for part of the scene.
    pub out: PathBuf,
    /// Seed of the generated scene (`ppf demo --seed`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Render the scene without sensor noise.
    #[arg(long)]
    pub no_noise: bool,
    /// Place these meshes instead of the generated parts: a folder of PLY meshes in mm, named
    /// by object id as `ppfd --models` takes them (`obj_000005.ply` is object 5); not the
    /// output's own `models/`, which the scene rewrites.
    #[arg(long, value_name = "DIR")]
    pub models: Option<PathBuf>,
    /// With --models: only these object ids, comma separated (default: every mesh of the
    /// folder).
    #[arg(long, value_delimiter = ',', value_parser = crate::common::object_id, requires = "models")]
    pub objects: Vec<u32>,
    /// Random boxes and cylinders placed on the table around the objects, hiding parts of
    /// them, 0 to 50 (the generated scene of `ppf demo` has none).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=50))]
    pub clutter: u32,
}

/// The meshes of `dir` with their object ids, in id order: those of `only` when it names any.
/// Refuses a folder without meshes, a file without an id, and an id that has no mesh there.
fn read_meshes(dir: &Path, only: &[u32]) -> Result<Vec<(u32, Mesh)>, String> {
    let entries =
        std::fs::read_dir(dir).map_err(|e| format!("cannot read {}: {e}", dir.display()))?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(format!("{}: no PLY meshes (*.ply) in it", dir.display()));
    }
    // The folder's own refusal first: `ppf model build`'s would offer its --id.
    for path in &paths {
        if ppfd::ppf_engine::object_id_of_file(path).is_none_or(|id| id == 0) {
            return Err(format!(
                "{}: no object id: the digits ending a mesh's name are its id, from 1 \
                 (obj_000005.ply is object 5); rename it, or move it out of the folder",
                path.display()
            ));
        }
    }
    let ids = crate::model::object_ids(&paths, None)?;
    if let Some(missing) = only.iter().find(|id| !ids.contains(id)) {
        let mut have = ids.clone();
        have.sort_unstable();
        let have: Vec<String> = have.iter().map(u32::to_string).collect();
        return Err(format!(
            "object {missing} has no mesh in {} (it has {})",
            dir.display(),
            have.join(", ")
        ));
    }
    let mut meshes = Vec::new();
    for (id, path) in ids.into_iter().zip(&paths) {
        if only.is_empty() || only.contains(&id) {
            // The reader's errors name the file; the checks of `ppf model build` refuse a mesh
            // in another unit, which would render as a speck or fill the room.
            let mesh = Mesh::from_ply_file(path).map_err(|e| e.to_string())?;
            sanity::check_mesh(&mesh).map_err(|e| format!("{}: {e}", path.display()))?;
            meshes.push((id, mesh));
        }
    }
    meshes.sort_by_key(|(id, _)| *id);
    Ok(meshes)
}

/// The entries of `source`'s `models_info.json` for `ids` (diameters and symmetries, which
/// `ppf eval` and `ppf score` read), or `None` when it has none.
fn models_info_for(source: &Path, ids: &[u32]) -> Result<Option<serde_json::Value>, String> {
    let path = source.join("models_info.json");
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let all: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not a models_info.json: {e}", path.display()))?;
    let kept: serde_json::Map<_, _> = all
        .into_iter()
        .filter(|(k, _)| k.parse::<u32>().is_ok_and(|id| ids.contains(&id)))
        .collect();
    Ok((!kept.is_empty()).then_some(serde_json::Value::Object(kept)))
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

/// The files of the dataset in the BOP layout (the meshes of `scene`'s objects, the scene,
/// `info` as `models_info.json`), each with its path below the dataset's folder.
fn dataset_files(
    meshes: &[(u32, &Mesh)],
    scene: &SyntheticScene,
    info: Option<&serde_json::Value>,
) -> Result<Vec<(PathBuf, Vec<u8>)>, String> {
    let f = &scene.frame;
    let k = f.intrinsics;
    let mut files = Vec::new();
    for (id, mesh) in meshes {
        let path = Path::new("models").join(format!("obj_{id:06}.ply"));
        files.push((path, mesh.to_ply_ascii().into_bytes()));
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
    let scene_dir = Path::new("test").join("000000");
    let pretty = |v: &serde_json::Value| serde_json::to_vec_pretty(v).expect("JSON values print");
    if let Some(info) = info {
        files.push((Path::new("models").join("models_info.json"), pretty(info)));
    }
    files.push((PathBuf::from("camera.json"), pretty(&camera)));
    files.push((scene_dir.join("scene_camera.json"), pretty(&scene_camera)));
    files.push((
        scene_dir.join("scene_gt.json"),
        pretty(&json!({"0": truth})),
    ));
    files.push((
        scene_dir.join("depth").join("000000.png"),
        depth_png(f.width, f.height, &f.depth)?,
    ));
    Ok(files)
}

/// Refuses an `out` that holds files other than `files` (paths below `out`): a reader of the
/// dataset would take them for part of the scene (an earlier `--models` run's objects, another
/// dataset's scenes or colour images). The files this run writes are replaced. The walk stops
/// at the tenth such file.
fn refuse_strangers(out: &Path, files: &[PathBuf]) -> Result<(), String> {
    const SHOWN: usize = 10;
    let mut strangers = Vec::new();
    let mut folders = vec![PathBuf::new()];
    while let Some(relative) = folders.pop() {
        let Ok(entries) = std::fs::read_dir(out.join(&relative)) else {
            continue;
        };
        for entry in entries.filter_map(|e| e.ok()) {
            let path = relative.join(entry.file_name());
            if entry.file_type().is_ok_and(|t| t.is_dir()) {
                folders.push(path);
            } else if !files.contains(&path) {
                strangers.push(path.display().to_string());
            }
        }
        if strangers.len() >= SHOWN {
            break;
        }
    }
    if strangers.is_empty() {
        return Ok(());
    }
    strangers.sort();
    strangers.truncate(SHOWN);
    Err(format!(
        "{} holds files that this scene does not write, which would be read as part of it \
         ({}{}): give a new or empty folder, or remove them",
        out.display(),
        strangers.join(", "),
        if strangers.len() == SHOWN {
            ", …"
        } else {
            ""
        }
    ))
}

/// Refuses `--models` naming the output's own `models/` folder: the scene rewrites its meshes
/// there (as ASCII with normals, which drops a source's colours and texture coordinates) and its
/// `models_info.json` (with only the objects placed).
fn refuse_own_models(source: &Path, out: &Path) -> Result<(), String> {
    let written = out.join("models");
    match (source.canonicalize(), written.canonicalize()) {
        (Ok(a), Ok(b)) if a == b => Err(format!(
            "{}: --models names the folder this scene writes its models into, which would \
             replace the meshes read from it: give another output folder, or copy the meshes \
             elsewhere first",
            source.display()
        )),
        _ => Ok(()),
    }
}

pub fn run(args: GenerateArgs) -> Result<(), String> {
    if let Some(dir) = &args.models {
        refuse_own_models(dir, &args.out)?;
    }
    let meshes: Vec<(u32, Mesh)> = match &args.models {
        Some(dir) => read_meshes(dir, &args.objects)?,
        None => Part::ALL
            .iter()
            .map(|p| (p.object_id(), p.mesh()))
            .collect(),
    };
    let ids: Vec<u32> = meshes.iter().map(|(id, _)| *id).collect();
    // Read before the scene is drawn: a malformed file is refused before any work.
    let info = match &args.models {
        Some(dir) => models_info_for(dir, &ids)?,
        None => None,
    };
    let refs: Vec<(u32, &Mesh)> = meshes.iter().map(|(id, m)| (*id, m)).collect();
    let noise = (!args.no_noise).then(NoiseModel::kinect);
    let scene = SyntheticScene::resting(args.seed, noise, args.clutter as usize, &refs)
        .map_err(|e| e.to_string())?;
    let files = dataset_files(&refs, &scene, info.as_ref())?;
    let paths: Vec<PathBuf> = files.iter().map(|(path, _)| path.clone()).collect();
    refuse_strangers(&args.out, &paths)?;
    let files: Vec<(PathBuf, Vec<u8>)> = files
        .into_iter()
        .map(|(path, bytes)| (args.out.join(path), bytes))
        .collect();
    crate::common::write_all(&files)?;
    println!(
        "wrote the generated scene of seed {} ({} objects, {} pieces of clutter) as a BOP dataset in {}",
        args.seed,
        scene.ground_truth.len(),
        args.clutter,
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, bytes: &[u8]) -> Result<(), String> {
        crate::common::write_all(&[(path.to_path_buf(), bytes.to_vec())])
    }

    /// Files of another dataset in the folder (a scene, a colour image, a file of targets) are
    /// refused by name, and nothing is written.
    #[test]
    fn a_folder_holding_another_datasets_files_is_refused() {
        let dir = crate::common::ScratchDir::create("ppf-generate-stray").unwrap();
        let out = dir.path().join("out");
        run(args(&out, 1)).unwrap();
        let depth = out.join("test/000000/depth/000000.png");
        let before = std::fs::read(&depth).unwrap();
        write(&out.join("test/000000/rgb/000000.png"), b"colour").unwrap();
        write(&out.join("test/000007/scene_gt.json"), b"{}").unwrap();
        let e = run(args(&out, 2)).unwrap_err();
        assert!(
            e.contains("test/000000/rgb/000000.png, test/000007/scene_gt.json")
                && e.contains("remove them"),
            "{e}"
        );
        assert_eq!(std::fs::read(&depth).unwrap(), before, "nothing written");
    }
    use crate::demo::parts_scene;
    use ppfd_bop::dataset::BopDataset;

    fn args(out: &Path, seed: u64) -> GenerateArgs {
        GenerateArgs {
            out: out.to_owned(),
            seed,
            no_noise: false,
            models: None,
            objects: Vec::new(),
            clutter: 0,
        }
    }

    /// What `ppf generate` writes reads back through the BOP reader as the scene it generated:
    /// the same depth values, intrinsics, truth and meshes.
    #[test]
    fn the_written_dataset_reads_back_as_the_generated_scene() {
        let dir = crate::common::ScratchDir::create("ppf-generate-test").unwrap();
        run(args(dir.path(), 3)).unwrap();
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

    /// A folder of three meshes, named by id, with a models_info.json that also names an object
    /// without a mesh.
    fn mesh_folder(dir: &Path) -> PathBuf {
        let models = dir.join("source");
        for part in [Part::LBracket, Part::ToothedDisc, Part::TPipe] {
            let path = models.join(format!("obj_{:06}.ply", part.object_id()));
            write(&path, part.mesh().to_ply_ascii().as_bytes()).unwrap();
        }
        let entry = |diameter: f32| {
            json!({"diameter": diameter, "min_x": -50.0, "min_y": -50.0, "min_z": -50.0,
                   "size_x": 100.0, "size_y": 100.0, "size_z": 100.0})
        };
        let info =
            json!({"1": entry(150.0), "3": entry(140.0), "4": entry(120.0), "9": entry(99.0)});
        write(
            &models.join("models_info.json"),
            info.to_string().as_bytes(),
        )
        .unwrap();
        models
    }

    /// With --models and --objects, the scene holds exactly the meshes asked for, each in view,
    /// their models_info entries come along, and --clutter puts more in view than the objects.
    #[test]
    fn a_cells_own_meshes_make_the_scene() {
        let dir = crate::common::ScratchDir::create("ppf-generate-models").unwrap();
        let source = mesh_folder(dir.path());
        let scene_of = |name: &str, clutter: u32| {
            let out = dir.path().join(name);
            run(GenerateArgs {
                models: Some(source.clone()),
                objects: vec![4, 1],
                clutter,
                ..args(&out, 11)
            })
            .unwrap();
            BopDataset::open(&out).unwrap()
        };
        let plain = scene_of("plain", 0);
        assert_eq!(plain.object_ids(), [1, 4]);
        let truth = plain.ground_truth(0, 0).unwrap();
        let ids: Vec<u32> = truth.iter().map(|g| g.obj_id).collect();
        assert_eq!(ids, [1, 4]);
        let frame = plain.depth_frame(0, 0).unwrap();
        for g in truth {
            let c = g.pose.translation.vector;
            let k = frame.intrinsics;
            let (u, v) = (k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy);
            assert!(
                (0.0..frame.width as f32).contains(&u) && (0.0..frame.height as f32).contains(&v),
                "object {} at pixel ({u}, {v}), out of view",
                g.obj_id
            );
        }
        let info: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(
            &std::fs::read(dir.path().join("plain/models/models_info.json")).unwrap(),
        )
        .unwrap();
        let keys: Vec<&str> = info.keys().map(String::as_str).collect();
        assert_eq!(keys, ["1", "4"]);
        assert_eq!(plain.model_info(4).unwrap().diameter_mm, 120.0);
        let read = Mesh::from_ply_file(plain.model_path(4).unwrap()).unwrap();
        assert_eq!(read.positions, Part::TPipe.mesh().positions);

        // Clutter stands between the table and the camera: nearer depth where there was table.
        let cluttered = scene_of("cluttered", 4);
        let near = |d: &BopDataset| {
            let f = d.depth_frame(0, 0).unwrap();
            f.depth.iter().filter(|&&z| z > 0 && z < 900).count()
        };
        assert_eq!(cluttered.ground_truth(0, 0).unwrap().len(), 2);
        let depth_plain = plain.depth_frame(0, 0).unwrap().depth;
        let depth_cluttered = cluttered.depth_frame(0, 0).unwrap().depth;
        let changed = depth_plain
            .iter()
            .zip(&depth_cluttered)
            .filter(|(a, b)| a.abs_diff(**b) > 20)
            .count();
        assert!(
            changed > 2_000,
            "4 pieces of clutter changed only {changed} pixels (near: {} against {})",
            near(&cluttered),
            near(&plain)
        );
    }

    /// Generating over an earlier run's folder replaces what it writes, but refuses a folder
    /// whose models the scene would not replace (another run's objects, or a models_info.json
    /// it does not write), which a reader would take for the scene's; nothing is written then.
    #[test]
    fn a_folder_holding_other_objects_is_refused() {
        let dir = crate::common::ScratchDir::create("ppf-generate-over").unwrap();
        let source = mesh_folder(dir.path());
        let out = dir.path().join("out");
        let with_models = || GenerateArgs {
            models: Some(source.clone()),
            objects: vec![3],
            ..args(&out, 2)
        };
        run(with_models()).unwrap();
        run(with_models()).unwrap();
        let depth = out.join("test/000000/depth/000000.png");
        let before = std::fs::read(&depth).unwrap();
        let e = run(args(&out, 5)).unwrap_err();
        assert!(
            e.contains("models_info.json") && !e.contains("obj_000003.ply"),
            "object 3 is a part the scene writes too: {e}"
        );
        assert_eq!(std::fs::read(&depth).unwrap(), before, "nothing written");
        std::fs::remove_file(out.join("models/models_info.json")).unwrap();
        run(args(&out, 5)).unwrap();
        let e = run(GenerateArgs {
            models: Some(source.clone()),
            objects: vec![4],
            ..args(&out, 2)
        })
        .unwrap_err();
        assert!(
            e.contains("models/obj_000001.ply, models/obj_000002.ply, models/obj_000003.ply")
                && e.contains("remove them"),
            "{e}"
        );
    }

    /// The output's own models folder as `--models` is refused before anything is read or
    /// written: its meshes stay as they are.
    #[test]
    fn the_outputs_own_models_folder_is_refused_as_source() {
        let dir = crate::common::ScratchDir::create("ppf-generate-own").unwrap();
        let source = mesh_folder(dir.path());
        let out = dir.path().join("out");
        run(GenerateArgs {
            models: Some(source),
            ..args(&out, 2)
        })
        .unwrap();
        let mesh = out.join("models/obj_000001.ply");
        // A mesh of the user's own, binary, in the folder the scene writes its models into.
        let mut theirs = std::fs::read(&mesh).unwrap();
        theirs.extend_from_slice(b"comment kept\n");
        std::fs::write(&mesh, &theirs).unwrap();
        let e = run(GenerateArgs {
            models: Some(out.join("models/../models")),
            ..args(&out, 3)
        })
        .unwrap_err();
        assert!(
            e.contains("--models names the folder this scene writes its models into"),
            "{e}"
        );
        assert_eq!(
            std::fs::read(&mesh).unwrap(),
            theirs,
            "the mesh is untouched"
        );
    }

    /// An object id without a mesh, a folder without meshes and a mesh in metres are refused
    /// with what is there.
    #[test]
    fn a_missing_mesh_is_named() {
        let dir = crate::common::ScratchDir::create("ppf-generate-missing").unwrap();
        let source = mesh_folder(dir.path());
        let e = run(GenerateArgs {
            models: Some(source),
            objects: vec![1, 2],
            ..args(&dir.path().join("out"), 1)
        })
        .unwrap_err();
        assert!(
            e.contains("object 2 has no mesh") && e.contains("(it has 1, 3, 4)"),
            "{e}"
        );
        let empty = dir.path().join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        let e = run(GenerateArgs {
            models: Some(empty),
            ..args(&dir.path().join("out"), 1)
        })
        .unwrap_err();
        assert!(e.contains("no PLY meshes"), "{e}");
        // A mesh whose name gives no id is named, with what to do in this command.
        let unnamed = dir.path().join("unnamed");
        write(
            &unnamed.join("bracket.ply"),
            Part::TPipe.mesh().to_ply_ascii().as_bytes(),
        )
        .unwrap();
        let e = run(GenerateArgs {
            models: Some(unnamed.clone()),
            ..args(&dir.path().join("out"), 1)
        })
        .unwrap_err();
        assert!(
            e.starts_with(&format!(
                "{}: no object id",
                unnamed.join("bracket.ply").display()
            )) && e.contains("rename it")
                && !e.contains("--id"),
            "{e}"
        );
        // A mesh in metres is refused with the file's name, before anything is written.
        let metres = dir.path().join("metres");
        let mut mesh = Part::TPipe.mesh();
        for p in &mut mesh.positions {
            p.coords /= 1000.0;
        }
        write(
            &metres.join("obj_000004.ply"),
            mesh.to_ply_ascii().as_bytes(),
        )
        .unwrap();
        let e = run(GenerateArgs {
            models: Some(metres.clone()),
            ..args(&dir.path().join("out"), 1)
        })
        .unwrap_err();
        assert!(
            e.starts_with(&format!("{}: ", metres.join("obj_000004.ply").display()))
                && e.contains("mm"),
            "{e}"
        );
        assert!(
            !dir.path().join("out").exists(),
            "nothing is written on a refusal"
        );
    }
}
