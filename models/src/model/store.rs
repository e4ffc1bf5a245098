//! The model store: one file per object model, written with rkyv and read back without decoding:
//! the file's bytes, copied once into a private read-only memory map, *are* the lookup table.
//! The copy makes a loaded model independent of its file: a file replaced or overwritten in place
//! while a daemon holds the model (a redeploy with `cp`) changes nothing in the daemon, where a
//! map of the file itself would take the daemon down (a truncated file's pages fault) or change
//! a validated table under its feet.
//!
//! Layout: a 32-byte header (magic `PPFDMODL`, format version, payload length, CRC-32 of the
//! payload), then the rkyv archive of [`crate::model::ModelData`]. Loading checks all of it and validates the
//! archive and the table's internal consistency before handing out an [`ObjectModel`]: a
//! truncated, corrupted, wrong-version or wrong-parameter file is refused, never trusted.
//!
//! A model file used as a cache of a mesh is checked with [`load_built_from_file`] (the same
//! parameters and the same bytes of the mesh file: no need to read the mesh) or, failing that,
//! [`load_expecting`] (the same parameters and the same mesh, [`crate::geometry::mesh::Mesh::fingerprint`],
//! whatever the file looks like).

use std::io::Write;
use std::path::{Path, PathBuf};

use memmap2::Mmap;

use crate::model::feature::key_count;
use crate::model::{ArchivedModelData, ModelParams, ObjectModel};
use crate::{Error, Result};

/// The file name extension of model files.
pub const EXTENSION: &str = "ppfm";
/// Bumped whenever [`crate::model::ModelData`], the table encoding or what a model is built
/// from a mesh changes. Version 2 added the mesh fingerprint, version 3 the CRC of the mesh
/// file; version 4 takes the normals of a mesh without normals from its faces split at creases
/// ([`crate::geometry::mesh::CREASE_ANGLE_DEG`]); version 5 added the object's symmetries;
/// version 6 reads meshes without the vertices that no face uses (they counted in the diameter).
/// Every file of an earlier version is refused: a cached model is rebuilt from its mesh, a model
/// file without one has to be rebuilt (`ppf model build`).
pub const FORMAT_VERSION: u32 = 6;
const MAGIC: &[u8; 8] = b"PPFDMODL";
const HEADER_LEN: usize = 32;

fn refuse(path: &Path, reason: impl Into<String>) -> Error {
    Error::ModelStore {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn io(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Where models built from meshes are cached unless told otherwise: `$PPFD_CACHE`, else
/// `$XDG_CACHE_HOME/ppfd`, else `~/.cache/ppfd`, else `ppfd-cache` in the system's temporary
/// directory. Never the mesh's own folder: a dataset's folder may be read-only or shared.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("PPFD_CACHE").filter(|d| !d.is_empty()) {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("ppfd");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h).join(".cache/ppfd");
    }
    std::env::temp_dir().join("ppfd-cache")
}

/// The file in `cache_dir` that caches the model of the mesh at `mesh`: the mesh's file stem and
/// a hash of its canonical path (`obj_000005-1a2b3c4d.ppfm`), so that meshes of one name in
/// different folders each keep their own. What the file holds is checked on loading
/// ([`load_built_from_file`], [`load_expecting`]); the name only keeps meshes apart.
pub fn cache_file(cache_dir: &Path, mesh: &Path) -> PathBuf {
    let canonical = std::fs::canonicalize(mesh).unwrap_or_else(|_| mesh.to_path_buf());
    let hash = crc32fast::hash(canonical.as_os_str().as_encoded_bytes());
    let stem = mesh.file_stem().unwrap_or_default().to_string_lossy();
    cache_dir.join(format!("{stem}-{hash:08x}.{EXTENSION}"))
}

/// Writes `model` to `path` (through a temporary file and a rename, so a reader never sees a
/// half-written model). The temporary file's name is this writer's own (process id and a
/// counter) and is created only if nothing is there: processes sharing a cache may build one
/// mesh at once, and a mapped model file must never be written to again.
pub fn save(model: &ObjectModel, path: &Path) -> Result<()> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static SAVES: AtomicU64 = AtomicU64::new(0);
    let payload = model.archive_bytes();
    let mut header = [0u8; HEADER_LEN];
    header[..8].copy_from_slice(MAGIC);
    header[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    header[16..24].copy_from_slice(&(payload.len() as u64).to_le_bytes());
    header[24..28].copy_from_slice(&crc32fast::hash(payload).to_le_bytes());
    remove_dead_writers_files(path);
    let tmp = path.with_extension(format!(
        "{EXTENSION}.{}-{}.tmp",
        std::process::id(),
        SAVES.fetch_add(1, Ordering::Relaxed)
    ));
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        f.write_all(&header)?;
        f.write_all(payload)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io(path, e)
    })
}

/// Removes the temporary files of [`save`]s of `path` whose process is gone (killed while it
/// wrote: a model file is tens of MB). A live process's file, or one whose name [`save`] does
/// not give, stays.
fn remove_dead_writers_files(path: &Path) {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    if !Path::new("/proc/self").exists() {
        return; // no way to tell a live writer from a dead one
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let prefix = format!("{}.", name.to_string_lossy());
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(writer) = file
            .to_str()
            .and_then(|f| f.strip_prefix(&prefix))
            .and_then(|rest| rest.strip_suffix(".tmp"))
            .and_then(|rest| rest.split_once('-'))
            .filter(|(_, n)| n.parse::<u64>().is_ok())
            .and_then(|(pid, _)| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if !Path::new(&format!("/proc/{writer}")).exists() {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// Reads `path` whole into a private read-only memory map (page aligned, as the archive needs);
/// refuses a file too short to hold the header.
fn read_private(path: &Path) -> Result<Mmap> {
    use std::io::Read;
    // Checked on the open handle: the path is not looked at again.
    let (mut file, len) = crate::file::open_regular(path)?;
    crate::limits::MODEL_FILE.check(path, len)?;
    let len = len as usize;
    if len < HEADER_LEN {
        return Err(refuse(
            path,
            format!("{len} bytes is shorter than the header"),
        ));
    }
    let mut map = memmap2::MmapMut::map_anon(len).map_err(|e| io(path, e))?;
    file.read_exact(&mut map[..len]).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            refuse(path, "the file became shorter while it was read")
        } else {
            io(path, e)
        }
    })?;
    let mut more = [0u8; 1];
    if file.read(&mut more).map_err(|e| io(path, e))? != 0 {
        return Err(refuse(path, "the file grew while it was read"));
    }
    let map = map.make_read_only().map_err(|e| io(path, e))?;
    Ok(map)
}

/// Reads and validates a model file.
pub fn load(path: &Path) -> Result<ObjectModel> {
    let map = read_private(path)?;
    if &map[..8] != MAGIC {
        return Err(refuse(path, "not a ppfd model file (bad magic)"));
    }
    let version = u32::from_le_bytes(map[8..12].try_into().unwrap());
    if version != FORMAT_VERSION {
        return Err(refuse(
            path,
            format!("format version {version}, this build reads version {FORMAT_VERSION}: rebuild the model"),
        ));
    }
    let payload_len = u64::from_le_bytes(map[16..24].try_into().unwrap()) as usize;
    let actual = map.len() - HEADER_LEN;
    if payload_len != actual {
        return Err(refuse(
            path,
            format!(
                "truncated or padded: header says {payload_len} payload bytes, file has {actual}"
            ),
        ));
    }
    let payload = &map[HEADER_LEN..];
    let crc = u32::from_le_bytes(map[24..28].try_into().unwrap());
    if crc32fast::hash(payload) != crc {
        return Err(refuse(path, "checksum mismatch: the file is corrupted"));
    }
    let data = rkyv::access::<ArchivedModelData, rkyv::rancor::Error>(payload)
        .map_err(|e| refuse(path, format!("invalid archive: {e}")))?;
    check_consistency(data).map_err(|reason| refuse(path, reason))?;
    Ok(ObjectModel::from_validated_map(map, HEADER_LEN))
}

/// The cache check: like [`load`], and refuses a model built with other parameters than
/// `expected` or from another mesh than the one whose [`Mesh::fingerprint`] is
/// `mesh_fingerprint`. A refusal means "rebuild": the caller has the mesh at hand.
///
/// [`Mesh::fingerprint`]: crate::geometry::mesh::Mesh::fingerprint
pub fn load_expecting(
    path: &Path,
    expected: &ModelParams,
    mesh_fingerprint: u32,
) -> Result<ObjectModel> {
    let model = load_built_with(path, expected)?;
    let built_from = model.mesh_fingerprint();
    if built_from != mesh_fingerprint {
        return Err(refuse(
            path,
            format!(
                "built from another mesh (fingerprint {built_from:08x}, the mesh now gives \
                 {mesh_fingerprint:08x}): rebuild the model"
            ),
        ));
    }
    Ok(model)
}

/// Like [`load`], and refuses a model built with other parameters than `expected`.
fn load_built_with(path: &Path, expected: &ModelParams) -> Result<ObjectModel> {
    let model = load(path)?;
    let params = model.params();
    if params != *expected {
        return Err(refuse(
            path,
            format!("built with {params:?}, expected {expected:?}: rebuild the model"),
        ));
    }
    Ok(model)
}

/// The CRC-32 of a mesh file's bytes, as [`load_built_from_file`] compares it.
pub fn source_crc(file_bytes: &[u8]) -> u32 {
    crc32fast::hash(file_bytes)
}

/// The fast cache check: like [`load`], and refuses a model built with other parameters than
/// `expected` or from a mesh file whose bytes had another [`source_crc`] than `source_crc`.
/// A refusal says nothing about the mesh itself: [`load_expecting`] may still accept the model.
pub fn load_built_from_file(
    path: &Path,
    expected: &ModelParams,
    source_crc: u32,
) -> Result<ObjectModel> {
    let model = load_built_with(path, expected)?;
    let built_from = model.source_crc();
    if built_from == 0 || built_from != source_crc {
        return Err(refuse(
            path,
            format!(
                "built from another mesh file (CRC {built_from:08x}, the file now gives \
                 {source_crc:08x})"
            ),
        ));
    }
    Ok(model)
}

/// What the matching code relies on without checking again: every index in range.
fn check_consistency(d: &ArchivedModelData) -> std::result::Result<(), String> {
    let params = rkyv::deserialize::<ModelParams, rkyv::rancor::Error>(&d.params)
        .map_err(|e| format!("parameters: {e}"))?;
    params.validate().map_err(|e| e.to_string())?;
    // What the file claims is checked against what it holds: a diameter read as millimetres
    // scales every distance of the method.
    let diameter = d.diameter_mm.to_native();
    if let Some(reason) = crate::limits::diameter_out_of_range(diameter) {
        return Err(reason);
    }
    let mesh: Vec<nalgebra::Point3<f32>> = d
        .mesh_positions
        .iter()
        .map(|p| nalgebra::Point3::new(p[0].to_native(), p[1].to_native(), p[2].to_native()))
        .collect();
    let measured = crate::model::sampling::diameter(&mesh);
    if (measured - diameter).abs() > 1e-3 * diameter {
        return Err(format!(
            "the file claims a diameter of {diameter} mm, its mesh measures {measured} mm"
        ));
    }
    let n = d.points.len();
    if d.normals.len() != n {
        return Err(format!("{n} points but {} normals", d.normals.len()));
    }
    if d.surface_normals.len() != d.surface_points.len() {
        return Err(format!(
            "{} surface points but {} normals",
            d.surface_points.len(),
            d.surface_normals.len()
        ));
    }
    if n < crate::limits::MIN_MODEL_POINTS {
        return Err(format!(
            "{n} model points, at least {}",
            crate::limits::MIN_MODEL_POINTS
        ));
    }
    if n > u16::MAX as usize {
        return Err(format!("{n} model points, at most {}", u16::MAX));
    }
    let keys = key_count(params.distance_bins, params.angle_bins);
    if d.table_offsets.len() != keys + 1 {
        return Err(format!(
            "{} table offsets, expected {}",
            d.table_offsets.len(),
            keys + 1
        ));
    }
    let mut prev = 0u32;
    for o in d.table_offsets.iter() {
        let o = o.to_native();
        if o < prev {
            return Err("table offsets decrease".into());
        }
        prev = o;
    }
    if d.table_offsets[0].to_native() != 0 || prev as usize != d.table_entries.len() {
        return Err(format!(
            "table offsets span {}..{}, entries are {}",
            d.table_offsets[0].to_native(),
            prev,
            d.table_entries.len()
        ));
    }
    if let Some(e) = d
        .table_entries
        .iter()
        .find(|e| (e.to_native() >> 16) as usize >= n)
    {
        return Err(format!(
            "table entry names model point {}, there are {n}",
            e.to_native() >> 16
        ));
    }
    let vertices = d.mesh_positions.len();
    if d.mesh_faces
        .iter()
        .flatten()
        .any(|i| i.to_native() as usize >= vertices)
    {
        return Err(format!(
            "a mesh face index is out of range ({vertices} vertices)"
        ));
    }
    crate::model::stored_symmetry(d)
        .and_then(|s| s.validate(diameter))
        .map_err(|e| e.to_string())?;
    let finite = |v: &[rkyv::Archived<f32>; 3]| v.iter().all(|x| x.to_native().is_finite());
    if !d.points.iter().all(finite)
        || !d.normals.iter().all(finite)
        || !d.surface_points.iter().all(finite)
        || !d.surface_normals.iter().all(finite)
        || !d.mesh_positions.iter().all(finite)
    {
        return Err("non-finite coordinates".into());
    }
    // Features, re-scoring and ICP divide by nothing but assume unit normals: a zero normal
    // turns every pose it touches into NaN.
    let unit = |v: &[rkyv::Archived<f32>; 3]| {
        let length = v.iter().map(|x| x.to_native().powi(2)).sum::<f32>().sqrt();
        (length - 1.0).abs() < 1e-3
    };
    if !d.normals.iter().all(unit) || !d.surface_normals.iter().all(unit) {
        return Err("normals that are not unit vectors".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tests::box_mesh;

    fn temp_dir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("ppfd-store-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn built() -> ObjectModel {
        ObjectModel::build(
            &box_mesh(50.0, 30.0, 20.0),
            3,
            "box",
            &ModelParams::default(),
        )
        .unwrap()
    }

    /// `model`'s data edited by `forge`, saved with a valid CRC to `path` and loaded back: the
    /// refusal's reason (panics when the file loads).
    fn forged_refusal(
        model: &ObjectModel,
        path: &std::path::Path,
        forge: impl FnOnce(&mut crate::model::ModelData),
    ) -> String {
        let mut data =
            rkyv::deserialize::<crate::model::ModelData, rkyv::rancor::Error>(model.data())
                .unwrap();
        forge(&mut data);
        let forged = ObjectModel {
            backing: crate::model::Backing::Owned(
                rkyv::to_bytes::<rkyv::rancor::Error>(&data).unwrap(),
            ),
            silhouette: std::sync::Mutex::new(None),
        };
        save(&forged, path).unwrap();
        match load(path) {
            Err(Error::ModelStore { reason, .. }) => reason,
            r => panic!("a forged model file was not refused: {r:?}"),
        }
    }

    /// A model file with a valid CRC whose diameter is not millimetres, or not what its own
    /// mesh measures, is refused: every distance of the method scales with it.
    #[test]
    fn a_model_file_whose_diameter_is_false_is_refused() {
        let dir = temp_dir("diameter");
        let model = built();
        let true_diameter = model.diameter_mm();
        for (claimed, said) in [
            (1e30, "micrometres"),
            (1e-6, "metres"),
            (2.0 * true_diameter, "its mesh measures"),
        ] {
            let reason = forged_refusal(&model, &dir.join("forged.ppfm"), |d| {
                d.diameter_mm = claimed
            });
            assert!(reason.contains(said), "{claimed}: {reason}");
        }
        let path = dir.join("true.ppfm");
        save(&model, &path).unwrap();
        assert_eq!(load(&path).unwrap().diameter_mm(), true_diameter);
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A model file with a valid CRC whose normals or surface are not usable is refused: zero
    /// normals turned every pose the detector returned into NaN.
    #[test]
    fn a_model_file_with_unusable_normals_or_surface_is_refused() {
        let dir = temp_dir("normals");
        type Forge = fn(&mut crate::model::ModelData);
        let forgeries: [(Forge, &str); 4] = [
            (
                |d| d.normals.iter_mut().for_each(|n| *n = [0.0; 3]),
                "unit vectors",
            ),
            (|d| d.surface_normals[3] = [0.0, 0.0, 2.0], "unit vectors"),
            (|d| d.surface_normals[5] = [f32::NAN; 3], "non-finite"),
            (|d| d.surface_points[0][1] = f32::INFINITY, "non-finite"),
        ];
        let model = built();
        for (i, (forge, said)) in forgeries.into_iter().enumerate() {
            let reason = forged_refusal(&model, &dir.join(format!("forged{i}.ppfm")), forge);
            assert!(reason.contains(said), "forgery {i}: {reason}");
        }
        let path = dir.join("true.ppfm");
        save(&model, &path).unwrap();
        assert!(load(&path).is_ok());
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A model's symmetries go into its file and come back; copies made for the file's CRC keep
    /// them; a file whose symmetry no object of its size can have is refused.
    #[test]
    fn symmetries_are_stored_and_read_back() {
        use crate::model::symmetry::Symmetry;
        let dir = temp_dir("symmetry");
        // The box's half turns about z and x (and so about y).
        let symmetry =
            Symmetry::generated(&["z:2".parse().unwrap(), "x:2".parse().unwrap()]).unwrap();
        assert_eq!(symmetry.order(), Some(4));
        let model = built().with_symmetry(&symmetry).unwrap();
        assert_eq!(model.symmetry(), symmetry);
        assert!(built().symmetry().is_none());
        assert_eq!(model.table(), built().table(), "the table does not change");
        let path = dir.join("box.ppfm");
        save(&model, &path).unwrap();
        let loaded = load(&path).unwrap();
        assert_eq!(loaded.symmetry(), symmetry);
        assert_eq!(loaded.with_source_crc(7).unwrap().symmetry(), symmetry);

        // A quarter turn is not the box's: refused before anything is stored.
        let quarter = Symmetry::generated(&["z:4".parse().unwrap()]).unwrap();
        let refused = built().with_symmetry(&quarter).unwrap_err().to_string();
        assert!(
            refused.starts_with("invalid parameter: box: symmetry: the object does not have it"),
            "{refused}"
        );

        // A forged file whose half turn moves the model by a metre.
        let reason = forged_refusal(&model, &path, |d| d.symmetries_discrete[0][4] = 1000.0);
        assert!(reason.contains("more than its diameter"), "{reason}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// Meshes of one name in two folders get two cache files; one mesh named two ways, one.
    #[test]
    fn cache_files_keep_meshes_of_one_name_apart() {
        let dir = temp_dir("names");
        for sub in ["a", "b"] {
            std::fs::create_dir_all(dir.join(sub)).unwrap();
            std::fs::write(dir.join(sub).join("obj_000001.ply"), "ply").unwrap();
        }
        let cache = dir.join("cache");
        let a = cache_file(&cache, &dir.join("a/obj_000001.ply"));
        let b = cache_file(&cache, &dir.join("b/obj_000001.ply"));
        assert_ne!(a, b);
        assert_eq!(a, cache_file(&cache, &dir.join("b/../a/obj_000001.ply")));
        assert_eq!(a.parent(), Some(cache.as_path()));
        let name = a.file_name().unwrap().to_str().unwrap();
        assert!(
            name.starts_with("obj_000001-") && name.ends_with(".ppfm"),
            "{name}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A save removes what a writer killed mid-write left of the same file (else it would stay
    /// for ever, tens of MB each), and keeps a live writer's file and files it did not name.
    #[test]
    fn a_save_removes_the_temporary_files_of_dead_writers() {
        let dir = temp_dir("deadtmp");
        let path = dir.join("obj_000003.ppfm");
        // Beyond Linux's largest pid (2^22): no process has it.
        let dead = dir.join("obj_000003.ppfm.4194305-0.tmp");
        let live = dir.join(format!("obj_000003.ppfm.{}-77.tmp", std::process::id()));
        let other = dir.join("obj_000003.ppfm.notes.tmp");
        let other_model = dir.join("obj_000004.ppfm.4194305-0.tmp");
        for f in [&dead, &live, &other, &other_model] {
            std::fs::write(f, "half a model").unwrap();
        }
        save(&built(), &path).unwrap();
        assert!(!dead.exists(), "a dead writer's file stayed");
        for f in [&live, &other, &other_model] {
            assert!(f.exists(), "{} removed", f.display());
        }
        assert_eq!(load(&path).unwrap().object_id(), 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn round_trip_gives_identical_model() {
        let dir = temp_dir("rt");
        let path = dir.join("box.ppfm");
        let model = built();
        save(&model, &path).unwrap();
        let loaded = load(&path).unwrap();
        assert!(loaded.is_mapped());
        assert_eq!(loaded.table(), model.table());
        assert_eq!(loaded.oriented_points(), model.oriented_points());
        assert_eq!(loaded.object_id(), 3);
        assert_eq!(loaded.name(), "box");
        assert_eq!(loaded.diameter_mm(), model.diameter_mm());
        assert_eq!(loaded.render_mesh().faces, model.render_mesh().faces);
        let fingerprint = box_mesh(50.0, 30.0, 20.0).fingerprint();
        assert_eq!(loaded.mesh_fingerprint(), fingerprint);
        assert!(load_expecting(&path, &ModelParams::default(), fingerprint).is_ok());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn the_file_check_wants_the_same_bytes_and_parameters() {
        let dir = temp_dir("source");
        let path = dir.join("box.ppfm");
        let crc = source_crc(b"ply\nformat ascii 1.0\n...");
        let model = built().with_source_crc(crc).unwrap();
        assert_eq!(model.source_crc(), crc);
        assert_eq!(model.table(), built().table(), "only the CRC changes");
        save(&model, &path).unwrap();
        let params = ModelParams::default();
        assert_eq!(
            load_built_from_file(&path, &params, crc)
                .unwrap()
                .source_crc(),
            crc
        );
        let other = load_built_from_file(&path, &params, crc ^ 1)
            .unwrap_err()
            .to_string();
        assert!(other.contains("another mesh file"), "{other}");
        let coarser = ModelParams {
            leaf_fraction: 0.07,
            ..params
        };
        assert!(load_built_from_file(&path, &coarser, crc).is_err());
        // A model built without a file (CRC 0) never passes this check.
        save(&built(), &path).unwrap();
        assert!(load_built_from_file(&path, &params, 0).is_err());
        std::fs::remove_dir_all(dir).unwrap();
    }

    fn refused(bytes: &[u8], dir: &Path, name: &str) -> String {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        match load(&p) {
            Err(Error::ModelStore { reason, .. }) => reason,
            other => panic!("{name}: expected refusal, got {other:?}"),
        }
    }

    /// A loaded model does not depend on its file: the file truncated and rewritten in place
    /// (what `cp other.ppfm model.ppfm` does), or overwritten at the same size, leaves the
    /// model as it was. A map of the file itself would fault on the truncated pages (SIGBUS)
    /// or show the new bytes under the validated table.
    #[test]
    fn a_loaded_model_survives_its_file_being_overwritten_in_place() {
        let dir = temp_dir("inplace");
        let path = dir.join("box.ppfm");
        let model = built();
        save(&model, &path).unwrap();
        let len = std::fs::metadata(&path).unwrap().len() as usize;
        for rewrite in [vec![0u8; 100], vec![0x5au8; len]] {
            let loaded = load(&path).unwrap();
            // Truncates, then writes: the inode stays, as with `cp` onto an existing file.
            std::fs::write(&path, &rewrite).unwrap();
            assert_eq!(
                std::fs::metadata(&path).unwrap().len() as usize,
                rewrite.len()
            );
            assert_eq!(loaded.table(), model.table());
            assert_eq!(loaded.oriented_points(), model.oriented_points());
            assert_eq!(loaded.surface_points(), model.surface_points());
            assert_eq!(loaded.render_mesh().faces, model.render_mesh().faces);
            save(&model, &path).unwrap();
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A folder or a FIFO is refused by name, without waiting for a writer.
    #[test]
    fn a_folder_or_a_fifo_is_not_a_model_file() {
        let dir = temp_dir("notfile");
        match load(&dir) {
            Err(Error::File { reason, .. }) => assert!(reason.contains("folder"), "{reason}"),
            r => panic!("{r:?}"),
        }
        let fifo = dir.join("pipe.ppfm");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            match load(&fifo) {
                Err(Error::File { reason, .. }) => {
                    assert!(reason.contains("not a regular file"), "{reason}")
                }
                r => panic!("{r:?}"),
            }
        } else {
            eprintln!("skipped the FIFO case: mkfifo is not available");
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn damaged_files_are_refused() {
        let dir = temp_dir("bad");
        let path = dir.join("good.ppfm");
        save(&built(), &path).unwrap();
        let good = std::fs::read(&path).unwrap();

        let truncated = &good[..good.len() - 100];
        assert!(refused(truncated, &dir, "trunc.ppfm").contains("truncated"));
        assert!(refused(&good[..10], &dir, "tiny.ppfm").contains("shorter than the header"));

        let mut corrupt = good.clone();
        let mid = good.len() / 2;
        corrupt[mid] ^= 0x5a;
        assert!(refused(&corrupt, &dir, "corrupt.ppfm").contains("checksum"));

        let mut version = good.clone();
        version[8] = 99;
        assert!(refused(&version, &dir, "version.ppfm").contains("format version 99"));
        // A file of the previous format asks to be rebuilt.
        version[8..12].copy_from_slice(&(FORMAT_VERSION - 1).to_le_bytes());
        let old = refused(&version, &dir, "old.ppfm");
        assert!(
            old.contains(&format!("format version {}", FORMAT_VERSION - 1))
                && old.contains("rebuild the model"),
            "{old}"
        );

        let mut magic = good.clone();
        magic[0] = b'X';
        assert!(refused(&magic, &dir, "magic.ppfm").contains("magic"));

        // A payload that passes the checksum but is not a valid archive.
        let mut garbage = good[..HEADER_LEN].to_vec();
        let junk = vec![0xABu8; 4096];
        garbage[16..24].copy_from_slice(&(junk.len() as u64).to_le_bytes());
        garbage[24..28].copy_from_slice(&crc32fast::hash(&junk).to_le_bytes());
        garbage.extend_from_slice(&junk);
        assert!(refused(&garbage, &dir, "garbage.ppfm").contains("invalid archive"));

        let other = ModelParams {
            angle_bins: 12,
            ..Default::default()
        };
        let fingerprint = box_mesh(50.0, 30.0, 20.0).fingerprint();
        match load_expecting(&path, &other, fingerprint) {
            Err(Error::ModelStore { reason, .. }) => assert!(reason.contains("expected")),
            r => panic!("{r:?}"),
        }
        assert!(matches!(
            load(&dir.join("missing.ppfm")),
            Err(Error::Io { .. })
        ));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_model_of_another_mesh_is_refused() {
        let dir = temp_dir("mesh");
        let path = dir.join("box.ppfm");
        save(&built(), &path).unwrap();
        let a = box_mesh(50.0, 30.0, 20.0).fingerprint();
        // One millimetre longer: same topology, same vertex count.
        let b = box_mesh(50.0, 30.0, 21.0).fingerprint();
        assert_ne!(a, b);
        assert!(load_expecting(&path, &ModelParams::default(), a).is_ok());
        match load_expecting(&path, &ModelParams::default(), b) {
            Err(Error::ModelStore { path: p, reason }) => {
                assert_eq!(p, path);
                assert_eq!(
                    reason,
                    format!(
                        "built from another mesh (fingerprint {a:08x}, the mesh now gives \
                         {b:08x}): rebuild the model"
                    )
                );
            }
            r => panic!("expected a refusal, got {r:?}"),
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}
