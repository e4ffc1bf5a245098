//! The model cache: the model of a mesh is built once, saved, and reused while the mesh is
//! unchanged. The daemon (meshes of its models folder, and `LoadModel`), the offline commands of
//! `ppf` (a dataset's meshes) and `ppf demo` (its generated parts) all get their models from
//! [`load_or_build`].
//!
//! A saved model is reused only when it was built with the same parameters and object id, and
//! either
//!
//! - from a mesh file with the same bytes: the CRC-32 of the file is recorded in the model, so
//!   the mesh is not even parsed ([`store::load_built_from_file`]), or
//! - from the same mesh, by its fingerprint ([`store::load_expecting`]): an ASCII file re-saved as
//!   binary keeps its model, which then records the file's new CRC.
//!
//! Otherwise the model is built and saved, replacing the file that was there (a cached model of
//! another mesh, another object id or an older format).
//!
//! The model of a mesh file then takes the symmetries that the `models_info.json` beside the
//! mesh gives its object (BOP layout; METHOD.md §1.8), in memory: the saved model keeps the
//! symmetry it was saved with, so that editing `models_info.json` needs no rebuild. Without
//! such a file or entry, the model keeps the symmetry saved in it (`ppf model build
//! --symmetry` writes one), none for a model built here. A symmetry the mesh does not have is
//! left out with a warning ([`CachedModel::symmetry_left_out`]), and the model keeps its own.
//! `ppf model build` follows the same rule. [`store::save`] writes through a
//! temporary file of the writer's own and a rename, so that processes sharing a cache never read
//! a half-written model, and removes the temporary files of writers killed meanwhile.
//!
//! ```no_run
//! use std::path::Path;
//! use ppfd::model_cache::{load_or_build, MeshSource, ModelFiles};
//! use ppfd_models::model::{store, ModelParams};
//!
//! let mesh = Path::new("models/obj_000005.ply");
//! let files = ModelFiles::of_mesh(mesh, Some(&store::default_cache_dir()));
//! let cached = load_or_build(MeshSource::File(mesh), 5, &ModelParams::default(), &files)?;
//! println!("{:?} from {:?}", cached.origin, cached.file);
//! # Ok::<(), ppfd_models::Error>(())
//! ```

use std::path::{Path, PathBuf};
use std::time::Instant;

use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};

/// The mesh a model is built from.
#[derive(Debug, Clone, Copy)]
pub enum MeshSource<'a> {
    /// A PLY file; its model is named after the file's stem.
    File(&'a Path),
    /// A mesh in memory (a generated part), and the name its model gets. With no file bytes to
    /// compare, only the fingerprint tells whether a saved model is this mesh's.
    Mesh {
        /// The mesh, mm.
        mesh: &'a Mesh,
        /// The name of its model.
        name: &'a str,
    },
}

/// Where the model of a mesh may already be, and where a model built now is saved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelFiles {
    /// Files that may hold the model, looked at in this order.
    pub candidates: Vec<PathBuf>,
    /// Where a model built now is saved; looked at among the candidates too.
    pub save_to: PathBuf,
}

impl ModelFiles {
    /// The files of the mesh file `mesh`: the model file beside it (`<mesh stem>.ppfm`) and its
    /// file in `cache_dir` ([`store::cache_file`]). A model built is saved in the cache, never
    /// beside the mesh (a dataset's folder may be read-only or shared), or beside it when there
    /// is no cache.
    pub fn of_mesh(mesh: &Path, cache_dir: Option<&Path>) -> ModelFiles {
        let beside = mesh.with_extension(store::EXTENSION);
        let save_to = match cache_dir {
            Some(dir) => store::cache_file(dir, mesh),
            None => beside.clone(),
        };
        let mut candidates = vec![beside];
        if save_to != candidates[0] {
            candidates.push(save_to.clone());
        }
        ModelFiles {
            candidates,
            save_to,
        }
    }

    /// One file, looked at and written.
    pub fn at(path: impl Into<PathBuf>) -> ModelFiles {
        let path = path.into();
        ModelFiles {
            candidates: vec![path.clone()],
            save_to: path,
        }
    }
}

/// How a model came to be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// Saved earlier from a mesh file with the same bytes: taken without parsing the mesh.
    SameFile,
    /// Saved earlier from the same mesh.
    SameMesh,
    /// Built now.
    Built,
}

/// The model of a mesh, and how it came.
pub struct CachedModel {
    /// The model, with the symmetries it takes (see the module documentation).
    pub model: ObjectModel,
    /// Whether it was reused from a saved file or built.
    pub origin: Origin,
    /// The file the model was read from: the candidate it was found in, or the file a model
    /// built now was saved to and read back from. `None` when a model built now could not be
    /// saved or read back.
    pub file: Option<PathBuf>,
    /// The candidates that held a model not taken, each with why: another object, another
    /// mesh, other parameters, another format version (`<file>: object 2, not 5: rebuilding`).
    pub rejected: Vec<String>,
    /// Why a model built now was not saved; the model is returned all the same.
    pub not_saved: Option<ppfd_models::Error>,
    /// The `models_info.json` whose symmetry the model has (see the module documentation).
    pub symmetry_from: Option<PathBuf>,
    /// Why the symmetry of the `models_info.json` beside the mesh was left out (the mesh does
    /// not have it), naming the file and the object.
    pub symmetry_left_out: Option<String>,
}

/// The model of `source` as object `object_id`, from the first of `files`' candidates that
/// holds it (see the module documentation), or built and saved at `files.save_to`; a mesh
/// file's model with the symmetries of the `models_info.json` beside it. Fails only when the
/// mesh or that `models_info.json` cannot be read or the model cannot be built; a failed save
/// is reported in [`CachedModel::not_saved`] and logged.
pub fn load_or_build(
    source: MeshSource<'_>,
    object_id: u32,
    params: &ModelParams,
    files: &ModelFiles,
) -> Result<CachedModel, ppfd_models::Error> {
    let mut cached = load_or_build_mesh_model(source, object_id, params, files)?;
    if let MeshSource::File(mesh) = source {
        take_symmetry_beside(&mut cached, mesh)?;
    }
    Ok(cached)
}

/// Gives `cached.model` the symmetry the `models_info.json` beside `mesh` gives its object, if
/// there is such an entry and the mesh has it (see the module documentation).
fn take_symmetry_beside(cached: &mut CachedModel, mesh: &Path) -> Result<(), ppfd_models::Error> {
    let id = cached.model.object_id();
    let beside = ppfd_bop::dataset::symmetry_beside(mesh, id).map_err(|e| match e {
        ppfd_bop::Error::Models(e) => e,
        ppfd_bop::Error::Io { path, source } => ppfd_models::Error::Io { path, source },
        ppfd_bop::Error::Dataset { path, reason } => ppfd_models::Error::File { path, reason },
        other => ppfd_models::Error::File {
            path: mesh.with_file_name("models_info.json"),
            reason: other.to_string(),
        },
    })?;
    let Some((symmetry, info)) = beside else {
        return Ok(());
    };
    if symmetry != cached.model.symmetry() {
        match cached.model.with_symmetry(&symmetry) {
            Ok(symmetric) => cached.model = symmetric,
            Err(e) => {
                tracing::warn!(
                    path = %mesh.display(),
                    models_info = %info.display(),
                    error = %e,
                    "the symmetry of models_info.json is left out"
                );
                cached.symmetry_left_out = Some(format!(
                    "{}: object {id}: the symmetry is left out: {e}",
                    info.display()
                ));
                return Ok(());
            }
        }
    }
    if !symmetry.is_none() {
        tracing::info!(
            path = %mesh.display(),
            models_info = %info.display(),
            symmetry = %symmetry.describe(),
            "model takes the symmetry of models_info.json"
        );
    }
    cached.symmetry_from = Some(info);
    Ok(())
}

/// [`load_or_build`] without the symmetries of `models_info.json`.
fn load_or_build_mesh_model(
    source: MeshSource<'_>,
    object_id: u32,
    params: &ModelParams,
    files: &ModelFiles,
) -> Result<CachedModel, ppfd_models::Error> {
    let began = Instant::now();
    let existing: Vec<&PathBuf> = files.candidates.iter().filter(|p| p.is_file()).collect();
    let found = |model, origin, file: &Path, rejected| CachedModel {
        model,
        origin,
        file: Some(file.to_path_buf()),
        rejected,
        not_saved: None,
        symmetry_from: None,
        symmetry_left_out: None,
    };

    let parsed: Mesh;
    let (mesh, name, source_crc): (&Mesh, String, Option<u32>) = match source {
        MeshSource::File(path) => {
            let bytes = ppfd_models::file::read_bounded(path, &ppfd_models::limits::MESH_FILE)?;
            let crc = store::source_crc(&bytes);
            // First without parsing the mesh: a model built from these very bytes.
            for &candidate in &existing {
                match store::load_built_from_file(candidate, params, crc) {
                    Ok(model) if model.object_id() == object_id => {
                        tracing::info!(path = %candidate.display(), "using the model built earlier from this file");
                        return Ok(found(model, Origin::SameFile, candidate, Vec::new()));
                    }
                    Ok(_) => {}
                    Err(e) => {
                        tracing::debug!(path = %candidate.display(), reason = %e, "not built from this file")
                    }
                }
            }
            parsed = Mesh::from_ply_reader(&bytes[..], path)?;
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
            (&parsed, stem.unwrap_or_else(|| "object".into()), Some(crc))
        }
        MeshSource::Mesh { mesh, name } => (mesh, name.to_owned(), None),
    };
    let read_ms = began.elapsed().as_millis() as u64;
    let fingerprint = mesh.fingerprint();
    let mut rejected = Vec::new();
    for &candidate in &existing {
        match store::load_expecting(candidate, params, fingerprint) {
            Ok(model) if model.object_id() == object_id => {
                tracing::info!(path = %candidate.display(), "using the model built earlier");
                // The same mesh in a rewritten file: record the file's new CRC, so that the
                // next load need not parse the mesh again.
                let model = match source_crc {
                    Some(crc) => match with_file_crc(model, candidate, crc) {
                        Ok(updated) => updated,
                        Err((model, e)) => {
                            tracing::debug!(path = %candidate.display(), error = %e, "CRC not recorded");
                            model
                        }
                    },
                    None => model,
                };
                return Ok(found(model, Origin::SameMesh, candidate, rejected));
            }
            Ok(model) => {
                tracing::info!(
                    path = %candidate.display(),
                    cached = model.object_id(),
                    wanted = object_id,
                    "model built earlier has another object id; not used"
                );
                rejected.push(format!(
                    "{}: object {}, not {object_id}: rebuilding",
                    candidate.display(),
                    model.object_id()
                ));
            }
            Err(e) => {
                tracing::info!(path = %candidate.display(), reason = %e, "model built earlier refused");
                rejected.push(e.to_string());
            }
        }
    }

    let started = Instant::now();
    let mut model = ObjectModel::build(mesh, object_id, &name, params)?;
    if let Some(crc) = source_crc {
        model = model.with_source_crc(crc)?;
    }
    let shown = match source {
        MeshSource::File(path) => path.display().to_string(),
        MeshSource::Mesh { name, .. } => name.to_owned(),
    };
    tracing::info!(
        path = %shown,
        object_id,
        points = model.point_count(),
        read_ms,
        build_ms = started.elapsed().as_millis() as u64,
        "model built from mesh"
    );
    let save_to = &files.save_to;
    if let Some(dir) = save_to.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    let mut built = CachedModel {
        model,
        origin: Origin::Built,
        file: None,
        rejected,
        not_saved: None,
        symmetry_from: None,
        symmetry_left_out: None,
    };
    match store::save(&built.model, save_to) {
        // Read the saved file back: what the next load will use is checked now.
        Ok(()) => {
            if let Ok(read_back) = store::load(save_to) {
                built.model = read_back;
                built.file = Some(save_to.clone());
            }
        }
        Err(e) => {
            tracing::warn!(path = %save_to.display(), error = %e, "built model not cached");
            built.not_saved = Some(e);
        }
    }
    Ok(built)
}

/// `model`, saved at `path` again with `crc` as its mesh file's CRC (nothing to do when it has
/// it already), and read back; on failure the model as it was, with the reason.
fn with_file_crc(
    model: ObjectModel,
    path: &Path,
    crc: u32,
) -> Result<ObjectModel, (ObjectModel, ppfd_models::Error)> {
    if model.source_crc() == crc {
        return Ok(model);
    }
    let updated = match ObjectModel::clone_with_source_crc(&model, crc) {
        Ok(updated) => updated,
        Err(e) => return Err((model, e)),
    };
    if let Err(e) = store::save(&updated, path) {
        return Err((model, e));
    }
    store::load(path).map_err(|e| (model, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ppfd-cache-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// A closed box of `size` mm.
    fn box_mesh([sx, sy, sz]: [f32; 3]) -> Mesh {
        ppfd_models::synthetic::parts::box_mesh(nalgebra::Vector3::new(sx, sy, sz))
    }

    /// An ASCII PLY file of a closed box of `size` mm.
    fn write_box_ply(path: &Path, size: [f32; 3]) {
        std::fs::write(path, box_mesh(size).to_ply_ascii()).unwrap();
    }

    fn diagonal([x, y, z]: [f32; 3]) -> f32 {
        (x * x + y * y + z * z).sqrt()
    }

    fn file_crc(path: &Path) -> u32 {
        store::source_crc(&std::fs::read(path).unwrap())
    }

    /// A mesh file's model, in the cache or beside the mesh: built once and saved, reused while
    /// the mesh is unchanged (by the file's bytes, else by the mesh), rebuilt and replaced when
    /// the mesh changes or the file is of an older format.
    #[test]
    fn a_mesh_files_model_is_reused_while_the_mesh_is_unchanged() {
        let (a, b) = ([60.0, 40.0, 20.0], [90.0, 40.0, 20.0]);
        let params = ModelParams::default();
        for with_cache in [false, true] {
            let root = scratch(if with_cache { "cache" } else { "beside" });
            let (models, cache) = (root.join("models"), root.join("cache"));
            std::fs::create_dir_all(&models).unwrap();
            let cache = with_cache.then_some(cache.as_path());
            let ply = models.join("obj_000001.ply");
            let files = ModelFiles::of_mesh(&ply, cache);
            let saved = &files.save_to;
            let load = || load_or_build(MeshSource::File(&ply), 1, &params, &files).unwrap();

            write_box_ply(&ply, a);
            let first = load();
            assert_eq!(first.origin, Origin::Built);
            assert!((first.model.diameter_mm() - diagonal(a)).abs() < 0.01);
            assert_eq!(
                first.file.as_ref(),
                Some(saved),
                "the built model is saved and read back"
            );
            assert_eq!(first.model.source_crc(), file_crc(&ply));
            drop(first);

            // Unchanged mesh: the model built earlier is used, not rebuilt. A copy named
            // "earlier", without the file's CRC, tells the two apart.
            let mesh = Mesh::from_ply_file(&ply).unwrap();
            let earlier = ObjectModel::build(&mesh, 1, "earlier", &params).unwrap();
            store::save(&earlier, saved).unwrap();
            let again = load();
            assert_eq!(
                (again.origin, again.model.name()),
                (Origin::SameMesh, "earlier")
            );
            drop(again);
            // Accepted by its mesh, it now records the file's CRC: the next load does not
            // parse the mesh.
            let recorded = store::load(saved).unwrap();
            assert_eq!(
                (recorded.name(), recorded.source_crc()),
                ("earlier", file_crc(&ply))
            );
            drop(recorded);
            assert_eq!(load().origin, Origin::SameFile);

            // A model saved under the file's CRC is taken as it is: shown with a model of a
            // cube of another name, which only this check can accept.
            let crc = file_crc(&ply);
            let cube = box_mesh([30.0, 30.0, 30.0]);
            let stand_in = ObjectModel::build(&cube, 1, "by-file", &params)
                .unwrap()
                .with_source_crc(crc)
                .unwrap();
            store::save(&stand_in, saved).unwrap();
            let by_file = load();
            assert_eq!(
                (by_file.origin, by_file.model.name()),
                (Origin::SameFile, "by-file")
            );
            drop(by_file);
            // Another CRC (the file changed since): the mesh decides, and rebuilds.
            let stale = ObjectModel::build(&cube, 1, "stale", &params)
                .unwrap()
                .with_source_crc(crc ^ 1)
                .unwrap();
            store::save(&stale, saved).unwrap();
            let rebuilt = load();
            assert_eq!(
                (rebuilt.origin, rebuilt.model.name()),
                (Origin::Built, "obj_000001")
            );
            assert!((rebuilt.model.diameter_mm() - diagonal(a)).abs() < 0.01);
            drop(rebuilt);

            // Another mesh under the same name: rebuilt, and the saved model replaced.
            write_box_ply(&ply, b);
            let replaced = load();
            assert_eq!(replaced.origin, Origin::Built);
            assert!(
                (replaced.model.diameter_mm() - diagonal(b)).abs() < 0.01,
                "diameter {} mm is the old mesh's",
                replaced.model.diameter_mm()
            );
            assert_eq!(replaced.model.name(), "obj_000001");
            drop(replaced);
            let on_disk = store::load(saved).unwrap();
            let fingerprint = Mesh::from_ply_file(&ply).unwrap().fingerprint();
            assert_eq!(on_disk.mesh_fingerprint(), fingerprint);
            assert_eq!(on_disk.source_crc(), file_crc(&ply));
            drop(on_disk);

            // A model file of an older format is rebuilt, not an error, and replaced.
            let mut old = std::fs::read(saved).unwrap();
            old[8..12].copy_from_slice(&(store::FORMAT_VERSION - 1).to_le_bytes());
            std::fs::write(saved, old).unwrap();
            let from_old = load();
            assert_eq!(from_old.origin, Origin::Built);
            assert_eq!(from_old.rejected.len(), 1, "{:?}", from_old.rejected);
            assert!(from_old.rejected[0].contains("format version"));
            drop(from_old);
            assert!(store::load(saved).is_ok(), "the old file is replaced");
            std::fs::remove_dir_all(&root).unwrap();
        }
    }

    /// With a cache, a model file beside the mesh is looked at first, read but never written.
    /// A mesh file's model takes the symmetry the `models_info.json` beside the mesh gives its
    /// object, in memory, whether built now or found; one the mesh does not have is left out,
    /// saying why; without an entry, the model keeps the symmetry saved in it.
    #[test]
    fn a_mesh_files_model_takes_the_symmetry_of_the_models_info_beside_it() {
        use ppfd_models::model::symmetry::Symmetry;
        use ppfd_models::synthetic::parts::SymmetricPart;
        let root = scratch("symmetry");
        let (models, cache) = (root.join("models"), root.join("cache"));
        std::fs::create_dir_all(&models).unwrap();
        let ply = models.join("obj_000005.ply");
        std::fs::write(&ply, SymmetricPart::UChannel.mesh().to_ply_ascii()).unwrap();
        let info = models.join("models_info.json");
        // BOP's row-major 4 × 4: a half turn about z, then a quarter turn (the part has no such).
        let write_info = |matrix: &str| {
            std::fs::write(
                &info,
                format!(
                    r#"{{"5": {{"diameter": 150.7, "min_x": -45, "min_y": -55, "min_z": -25,
                        "size_x": 90, "size_y": 110, "size_z": 50,
                        "symmetries_discrete": [[{matrix}]]}}}}"#
                ),
            )
            .unwrap()
        };
        let half = "-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1";
        let quarter = "0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1";
        let files = ModelFiles::of_mesh(&ply, Some(&cache));
        let params = ModelParams::default();
        let load = || load_or_build(MeshSource::File(&ply), 5, &params, &files).unwrap();

        write_info(half);
        let built = load();
        assert_eq!(built.origin, Origin::Built);
        assert_eq!(built.model.symmetry().order(), Some(2));
        assert_eq!(built.symmetry_from.as_ref(), Some(&info));
        // In memory only: the cache holds the mesh's model, and gives it the symmetry again.
        assert!(store::load(&files.save_to).unwrap().symmetry().is_none());
        let found = load();
        assert_eq!(found.origin, Origin::SameFile);
        assert_eq!(found.model.symmetry(), built.model.symmetry());

        write_info(quarter);
        let refused = load();
        assert!(refused.model.symmetry().is_none());
        let why = refused.symmetry_left_out.expect("left out");
        assert!(
            why.contains("models_info.json: object 5: the symmetry is left out")
                && why.contains("does not have it"),
            "{why}"
        );

        // No entry for the object: a model beside the mesh keeps the symmetry saved in it. One
        // `ppf model build --symmetry` wrote, with the file's CRC: taken before the cached one.
        std::fs::write(&info, "{}").unwrap();
        let turned = Symmetry::generated(&["z:2".parse().unwrap()]).unwrap();
        let beside = ply.with_extension(store::EXTENSION);
        let own = ObjectModel::build(&SymmetricPart::UChannel.mesh(), 5, "own", &params)
            .unwrap()
            .with_source_crc(file_crc(&ply))
            .unwrap()
            .with_symmetry(&turned)
            .unwrap();
        store::save(&own, &beside).unwrap();
        let kept = load();
        assert_eq!(kept.model.name(), "own");
        assert_eq!(kept.model.symmetry(), turned);
        assert!(kept.symmetry_from.is_none() && kept.symmetry_left_out.is_none());
        // A malformed models_info.json is an error naming it, of a file (a load answered
        // "model error", not "internal").
        std::fs::write(&info, "{").unwrap();
        let e = load_or_build(MeshSource::File(&ply), 5, &params, &files)
            .err()
            .expect("refused");
        assert!(matches!(e, ppfd_models::Error::File { .. }), "{e:?}");
        let e = e.to_string();
        assert!(
            e.contains("models_info.json") && e.contains("not valid JSON"),
            "{e}"
        );
        std::fs::remove_dir_all(root).unwrap();
    }

    #[test]
    fn a_model_beside_the_mesh_is_read_but_never_written() {
        let root = scratch("beside-with-cache");
        let (models, cache) = (root.join("models"), root.join("cache"));
        std::fs::create_dir_all(&models).unwrap();
        std::fs::create_dir_all(&cache).unwrap();
        let ply = models.join("obj_000001.ply");
        write_box_ply(&ply, [60.0, 40.0, 20.0]);
        let params = ModelParams::default();
        let files = ModelFiles::of_mesh(&ply, Some(&cache));
        assert_eq!(
            files.candidates,
            [
                models.join("obj_000001.ppfm"),
                store::cache_file(&cache, &ply)
            ]
        );
        assert_eq!(files.save_to, files.candidates[1]);
        let mesh = Mesh::from_ply_file(&ply).unwrap();
        let beside = ObjectModel::build(&mesh, 1, "beside", &params)
            .unwrap()
            .with_source_crc(file_crc(&ply))
            .unwrap();
        store::save(&beside, &files.candidates[0]).unwrap();
        let found = load_or_build(MeshSource::File(&ply), 1, &params, &files).unwrap();
        assert_eq!(found.model.name(), "beside");
        assert_eq!(found.file.as_ref(), Some(&files.candidates[0]));
        // Of another object id, it is rebuilt into the cache and left as it was.
        let before = std::fs::read(&files.candidates[0]).unwrap();
        let rebuilt = load_or_build(MeshSource::File(&ply), 4, &params, &files).unwrap();
        assert_eq!(rebuilt.origin, Origin::Built);
        assert_eq!(rebuilt.file.as_ref(), Some(&files.save_to));
        assert_eq!(std::fs::read(&files.candidates[0]).unwrap(), before);
        drop((found, rebuilt));
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A generated mesh's model file: kept while the mesh and the object id are the same,
    /// rebuilt (saying why) for another mesh or another object id.
    #[test]
    fn a_generated_meshs_model_is_rebuilt_for_another_mesh_or_object() {
        let dir = scratch("generated");
        let path = dir.join("part_000002.ppfm");
        let files = ModelFiles::at(&path);
        let params = ModelParams::default();
        let (older, newer) = (box_mesh([40.0, 40.0, 10.0]), box_mesh([40.0, 30.0, 10.0]));
        let load = |mesh, id| {
            let source = MeshSource::Mesh { mesh, name: "part" };
            load_or_build(source, id, &params, &files).unwrap()
        };
        assert_eq!(load(&older, 2).origin, Origin::Built);
        assert_eq!(
            load(&older, 2).origin,
            Origin::SameMesh,
            "the same mesh keeps its model"
        );
        let another_mesh = load(&newer, 2);
        assert_eq!(another_mesh.origin, Origin::Built);
        assert!(another_mesh.rejected[0].contains("built from another mesh"));
        drop(another_mesh);
        let model = store::load(&path).unwrap();
        assert_eq!(model.mesh_fingerprint(), newer.fingerprint());
        assert!((model.diameter_mm() - diagonal([40.0, 30.0, 10.0])).abs() < 0.01);
        drop(model);
        let another_object = load(&newer, 5);
        assert_eq!(another_object.origin, Origin::Built);
        assert_eq!(
            another_object.rejected,
            [format!("{}: object 2, not 5: rebuilding", path.display())]
        );
        drop(another_object);
        assert_eq!(store::load(&path).unwrap().object_id(), 5);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A model built is saved through a temporary file of its own, which does not stay, and
    /// the save removes what a writer killed while it wrote the same file left.
    #[test]
    fn a_build_leaves_no_temporary_file_and_removes_those_of_dead_writers() {
        let root = scratch("tmp");
        let (ply, cache) = (root.join("obj_000003.ply"), root.join("cache"));
        write_box_ply(&ply, [50.0, 30.0, 20.0]);
        let files = ModelFiles::of_mesh(&ply, Some(&cache));
        std::fs::create_dir_all(&cache).unwrap();
        // Beyond Linux's largest pid (2^22): no process has it.
        let name = files.save_to.file_name().unwrap().to_string_lossy();
        let dead = cache.join(format!("{name}.4194305-0.tmp"));
        std::fs::write(&dead, "half a model").unwrap();
        let params = ModelParams::default();
        let built = load_or_build(MeshSource::File(&ply), 3, &params, &files).unwrap();
        assert_eq!(built.origin, Origin::Built);
        drop(built);
        let left: Vec<_> = std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, [files.save_to.file_name().unwrap()], "{left:?}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
