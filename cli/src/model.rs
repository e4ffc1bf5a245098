//! `ppf model`: build model files from meshes, show what one holds, and benchmark building and
//! loading.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::sanity;
use ppfd_models::model::store;
use ppfd_models::model::symmetry::{Symmetry, SymmetryElement};
use ppfd_models::model::{ModelParams, ObjectModel};

use crate::common::ScratchDir;

#[derive(Subcommand, Debug)]
pub enum ModelCommand {
    /// Build model files (`<name>.ppfm`) from PLY meshes.
    Build(BuildArgs),
    /// Print what a model file holds.
    Info {
        /// A `.ppfm` file.
        file: PathBuf,
    },
    /// Time building and loading models and print a table (release build for real figures).
    Bench(BenchArgs),
}

#[derive(Args, Debug)]
pub struct BuildArgs {
    /// PLY meshes, in millimetres. The digits ending a file's name give its object id, as
    /// `ppfd` takes them (`obj_000005.ply` is object 5, `duck7.ply` object 7); a name without
    /// them needs `--id`.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Folder to write the model files into (made if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Object id for a single mesh, from 1 (instead of the digits ending its name).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub id: Option<u32>,
    /// Multiply every coordinate by this to get millimetres: 1000 for a mesh in metres, 10 in
    /// centimetres, 25.4 in inches. A mesh whose diameter is not 2 mm to 10 m is refused, and
    /// one below 20 mm warned of.
    #[arg(long, value_parser = positive_scale)]
    pub scale: Option<f32>,
    /// The object's symmetry, for a single mesh; repeatable, the symmetry is all the given turns
    /// combined. `AXIS:N` is every turn by a multiple of 360°/N about the axis (N 2 to 100),
    /// `AXIS:inf` any turn about it; either may end in `@X,Y,Z`, a point of the axis in the
    /// model's mm, after --scale (else the model's origin). `AXIS` is x, y, z or a direction
    /// A,B,C: `z:2`, `z:inf --symmetry x:2`, `0,1,1:4@0,0,12.5`. `none` for no symmetry. A
    /// symmetry the mesh does not have is refused. Without it, a mesh takes the symmetries of
    /// its entry in the `models_info.json` beside it (BOP layout), if there is one, as the
    /// daemon and `ppf eval` do; one the mesh does not have is then left out with a warning.
    #[arg(long, value_parser = symmetry_arg, value_name = "AXIS:N|AXIS:inf|none")]
    pub symmetry: Vec<SymmetryArg>,
}

/// One `--symmetry` value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SymmetryArg {
    /// `none`: no symmetry, whatever `models_info.json` says.
    None,
    Element(SymmetryElement),
}

fn symmetry_arg(text: &str) -> Result<SymmetryArg, String> {
    if text.trim().eq_ignore_ascii_case("none") {
        return Ok(SymmetryArg::None);
    }
    text.parse().map(SymmetryArg::Element)
}

/// The symmetry `--symmetry` gives (`None` when not given): refuses it for several meshes, and
/// `none` with turns.
fn given_symmetry(args: &BuildArgs) -> Result<Option<Symmetry>, String> {
    if args.symmetry.is_empty() {
        return Ok(None);
    }
    if args.meshes.len() > 1 {
        return Err(
            "--symmetry applies to a single mesh; with several, each takes the \
                    symmetries of the models_info.json beside it, if any"
                .into(),
        );
    }
    let elements: Vec<SymmetryElement> = args
        .symmetry
        .iter()
        .filter_map(|a| match a {
            SymmetryArg::Element(e) => Some(*e),
            SymmetryArg::None => None,
        })
        .collect();
    if elements.len() < args.symmetry.len() {
        return match elements.len() {
            0 => Ok(Some(Symmetry::default())),
            _ => Err("--symmetry none says the object has no symmetry: give it alone".into()),
        };
    }
    Symmetry::generated(&elements)
        .map(Some)
        .map_err(|e| format!("--symmetry: {e}"))
}

/// A `--scale` factor: finite and positive.
fn positive_scale(text: &str) -> Result<f32, String> {
    match text.parse::<f32>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!(
            "{text:?}: a finite positive number (1000 turns metres into millimetres)"
        )),
    }
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// PLY meshes to build.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Repetitions per model, 1 to 1000; the table shows medians.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,
}

/// Refuses a path that cannot be a mesh file before it is read as one (a folder would be
/// "malformed PLY: bad header: Is a directory").
fn check_mesh_path(path: &Path) -> Result<(), String> {
    if path.is_dir() {
        return Err(format!(
            "{}: is a directory; give PLY mesh files (e.g. {}/*.ply)",
            path.display(),
            path.display()
        ));
    }
    Ok(())
}

/// The object id of each mesh: `id` (`--id`, a single mesh), else the digits ending the file's
/// name, by `ppfd`'s own rule (`obj_000005.ply` → 5, `duck7.ply` → 7), so that a model built
/// here has the id the daemon gives the mesh. Refuses, naming the file, a folder, a name
/// without an id, id 0, and two meshes of one id (two models of one object).
pub(crate) fn object_ids(meshes: &[PathBuf], id: Option<u32>) -> Result<Vec<u32>, String> {
    if id.is_some() && meshes.len() > 1 {
        let e = "--id applies to a single mesh; with several, the digits ending each file's \
                 name give its object id (obj_000005.ply is object 5)";
        return Err(e.into());
    }
    let mut ids: Vec<u32> = Vec::with_capacity(meshes.len());
    for path in meshes {
        check_mesh_path(path)?;
        let id = match id.or_else(|| ppfd::ppf_engine::object_id_of_file(path)) {
            Some(0) => {
                return Err(format!(
                    "{}: the digits ending its name give object id 0; ids start at 1: \
                     rename the file or give --id",
                    path.display()
                ))
            }
            Some(id) => id,
            None => {
                return Err(format!(
                    "{}: no object id: name the file obj_<id>.ply (the digits ending the name \
                     are the id, as for ppfd; at most {}) or give --id",
                    path.display(),
                    u32::MAX
                ))
            }
        };
        if let Some(j) = ids.iter().position(|&known| known == id) {
            return Err(if meshes[j] == *path {
                format!("{} is given twice", path.display())
            } else {
                format!(
                    "{} and {} are both object {id} (the digits ending a file's name are its \
                     id): one model per object; rename one",
                    meshes[j].display(),
                    path.display()
                )
            });
        }
        ids.push(id);
    }
    Ok(ids)
}

fn name_of(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into())
}

pub fn run(cmd: ModelCommand) -> Result<(), Box<dyn std::error::Error>> {
    match cmd {
        ModelCommand::Build(args) => build(args),
        ModelCommand::Info { file } => info(&file),
        ModelCommand::Bench(args) => bench(args),
    }
}

fn build(args: BuildArgs) -> Result<(), Box<dyn std::error::Error>> {
    // All refusals before anything is built.
    let ids = object_ids(&args.meshes, args.id)?;
    let given = given_symmetry(&args)?;
    let mut symmetries = Vec::with_capacity(ids.len());
    for (path, &id) in args.meshes.iter().zip(&ids) {
        symmetries.push(match &given {
            Some(symmetry) => (symmetry.clone(), None),
            // In the mesh's units, as the mesh is.
            None => match ppfd_bop::dataset::symmetry_beside(path, id)? {
                Some((symmetry, from)) => (symmetry.scaled(args.scale.unwrap_or(1.0)), Some(from)),
                None => (Symmetry::default(), None),
            },
        });
    }
    if args.out.exists() && !args.out.is_dir() {
        return Err(format!(
            "--out {}: is a file; --out takes a folder to write the model files into (made if \
             missing)",
            args.out.display()
        )
        .into());
    }
    // A model file of another object is not overwritten: built with --id, it is named after
    // a mesh of another id, and the next build of that mesh would replace it unseen.
    for (path, &id) in args.meshes.iter().zip(&ids) {
        let out = args
            .out
            .join(format!("{}.{}", name_of(path), store::EXTENSION));
        if let Ok(there) = store::load(&out) {
            if there.object_id() != id {
                return Err(format!(
                    "{} holds the model of object {}, and {} is object {id}: not overwritten \
                     (remove it, or give --out another folder)",
                    out.display(),
                    there.object_id(),
                    path.display()
                )
                .into());
            }
        }
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
    let bar = ProgressBar::new(args.meshes.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} [{elapsed}]").unwrap());
    let params = ModelParams::default();
    let mut failures = 0;
    for ((path, &id), (symmetry, symmetry_from)) in args.meshes.iter().zip(&ids).zip(&symmetries) {
        let name = name_of(path);
        bar.set_message(name.clone());
        let result = ppfd_models::file::read_bounded(path, &ppfd_models::limits::MESH_FILE)
            .and_then(|bytes| {
                let mut mesh = Mesh::from_ply_reader(&bytes[..], path)?;
                // The model records the CRC of the file's very bytes, as the daemon's own
                // models do, so that the daemon takes it, beside the mesh, before the model it
                // cached of the mesh (whose symmetry may differ), and, with --scale, instead of
                // the mesh, which it would refuse as it is.
                let (model, report) = match args.scale {
                    Some(factor) => {
                        mesh.scale(factor);
                        // The sizes a refusal gives are the scaled mesh's: said so.
                        ObjectModel::build_with_report(&mesh, id, &name, &params).map_err(|e| {
                            match e {
                                ppfd_models::Error::InvalidMesh(reason) => {
                                    ppfd_models::Error::InvalidMesh(format!(
                                        "scaled by --scale {factor}: {reason}"
                                    ))
                                }
                                e => e,
                            }
                        })?
                    }
                    None => ObjectModel::build_with_report(&mesh, id, &name, &params)?,
                };
                Ok((model.with_source_crc(store::source_crc(&bytes))?, report))
            })
            .and_then(|(model, report)| {
                if symmetry.is_none() {
                    return Ok((model, report, None));
                }
                match model.with_symmetry(symmetry) {
                    Ok(symmetric) => Ok((symmetric, report, None)),
                    // Read beside the mesh: left out, as the daemon and `ppf eval` leave it.
                    Err(e) if symmetry_from.is_some() => Ok((model, report, Some(e))),
                    Err(e) => Err(e),
                }
            })
            .and_then(|(model, report, left_out)| {
                let out = args.out.join(format!("{name}.{}", store::EXTENSION));
                store::save(&model, &out).map(|_| (model, report, out, left_out))
            });
        match result {
            // `suspend`, not `ProgressBar::println`: that prints nothing when the bar is
            // hidden (output not a terminal), and a script would see no reason for a failure.
            Ok((model, report, out, left_out)) => bar.suspend(|| {
                println!(
                    "{}: object {id}, {}, {} points, {} table entries, {:.1} MB -> {}",
                    path.display(),
                    report.describe(),
                    model.point_count(),
                    model.table_entry_count(),
                    model.byte_size() as f64 / 1e6,
                    out.display()
                );
                if report.inward_normals {
                    println!(
                        "note: {}: the normals of this closed mesh pointed inward; the model \
                         has them flipped to point outward",
                        path.display()
                    );
                }
                if let Some(warning) = report.small_warning() {
                    eprintln!("warning: {}: {warning}", path.display());
                }
                if let (Some(e), Some(info)) = (&left_out, symmetry_from) {
                    eprintln!(
                        "warning: {}: the symmetry of {} is left out, the model has none: {e}",
                        path.display(),
                        info.display()
                    );
                } else if !symmetry.is_none() {
                    let from = match symmetry_from {
                        Some(info) => format!(" (from {})", info.display()),
                        None => String::new(),
                    };
                    println!(
                        "{}: symmetry: {}{from}",
                        path.display(),
                        symmetry.describe()
                    );
                }
            }),
            Err(e) => {
                failures += 1;
                bar.suspend(|| eprintln!("error: {e}"));
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    if failures > 0 {
        return Err(format!("{failures} of {} meshes failed", args.meshes.len()).into());
    }
    Ok(())
}

fn info(file: &Path) -> Result<(), Box<dyn std::error::Error>> {
    if file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
    {
        return Err(format!(
            "{} is a mesh; `ppf model info` reads model files (.ppfm): build one with \
             `ppf model build {} --out <dir>`",
            file.display(),
            file.display()
        )
        .into());
    }
    if file.is_dir() {
        return Err(format!(
            "{} is a folder; `ppf model info` reads one model file (.ppfm): {}",
            file.display(),
            match first_model_file(file) {
                Some(model) => format!("give one, e.g. {}", model.display()),
                None => "this folder holds none".to_owned(),
            }
        )
        .into());
    }
    let model = store::load(file)?;
    let p = model.params();
    let table = model.table();
    let used = table.offsets.windows(2).filter(|w| w[1] > w[0]).count();
    let largest = table
        .offsets
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(0);
    println!("file            {}", file.display());
    println!("format version  {}", store::FORMAT_VERSION);
    println!("object id       {}", model.object_id());
    println!("name            {}", model.name());
    let mesh = model.render_mesh();
    println!("diameter        {:.3} mm", model.diameter_mm());
    match sanity::check_mesh(&mesh) {
        Ok(report) => {
            let s = report.size_mm;
            println!("size            {:.1} × {:.1} × {:.1} mm", s.x, s.y, s.z);
            let surface = match (report.closed, report.inward_normals) {
                (true, false) => "closed, normals outward",
                (true, true) => "closed, normals INWARD (rebuild it with this build of ppf)",
                (false, _) => "open (normals not checked)",
            };
            println!("surface         {surface}");
        }
        Err(e) => println!("sanity          refused: {e}"),
    }
    println!(
        "model points    {} (leaf {:.2} mm)",
        model.point_count(),
        p.leaf_fraction * model.diameter_mm()
    );
    println!("surface points  {}", model.surface_points().len());
    println!(
        "table entries   {} in {} of {} keys (largest key: {})",
        model.table_entry_count(),
        used,
        table.offsets.len() - 1,
        largest
    );
    println!(
        "mesh            {} vertices, {} triangles, fingerprint {:08x}",
        mesh.positions.len(),
        mesh.faces.len(),
        model.mesh_fingerprint()
    );
    println!("symmetry        {}", model.symmetry().describe());
    println!("bytes           {:.2} MB", model.byte_size() as f64 / 1e6);
    println!("parameters      {p:?}");
    Ok(())
}

/// The first model file in `dir` by name, for an example.
fn first_model_file(dir: &Path) -> Option<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case(store::EXTENSION))
        })
        .collect();
    files.sort();
    files.into_iter().next()
}

/// `ppf model bench`: builds each mesh's model `repeat` times and reports the times and sizes.
fn bench(args: BenchArgs) -> Result<(), Box<dyn std::error::Error>> {
    for path in &args.meshes {
        check_mesh_path(path)?;
    }
    // Removed on every way out, a failed mesh included.
    let scratch = ScratchDir::create("ppf-model-bench")?;
    let dir = scratch.path();
    let repeat = args.repeat;
    println!("| model | build (ms) | points | table entries | size (MB) | load (ms) | D (mm) |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let params = ModelParams::default();
    let mut failed = 0;
    for (i, path) in args.meshes.iter().enumerate() {
        // A mesh that fails is said and the others measured, as `ppf model build` goes on.
        let row = || -> Result<String, Box<dyn std::error::Error>> {
            let mesh = Mesh::from_ply_file(path)?;
            // The id only seeds the sampling here: a name without one is numbered by position.
            let id = ppfd::ppf_engine::object_id_of_file(path)
                .filter(|&id| id > 0)
                .unwrap_or(i as u32 + 1);
            let name = name_of(path);
            let mut builds = Vec::new();
            let mut model = None;
            for _ in 0..repeat {
                let t = Instant::now();
                model = Some(ObjectModel::build(&mesh, id, &name, &params)?);
                builds.push(t.elapsed());
            }
            let model = model.expect("at least one run");
            let file = dir.join(format!("{name}.{}", store::EXTENSION));
            store::save(&model, &file)?;
            let mut loads = Vec::new();
            for _ in 0..repeat {
                let t = Instant::now();
                let loaded = store::load(&file)?;
                loads.push(t.elapsed());
                assert_eq!(loaded.table_entry_count(), model.table_entry_count());
            }
            Ok(format!(
                "| {name} | {:.0} | {} | {} | {:.2} | {:.2} | {:.2} |",
                crate::common::median_ms(&builds),
                model.point_count(),
                model.table_entry_count(),
                model.byte_size() as f64 / 1e6,
                crate::common::median_ms(&loads),
                model.diameter_mm()
            ))
        };
        match row() {
            Ok(line) => println!("{line}"),
            Err(e) => {
                failed += 1;
                eprintln!("error: {e}");
            }
        }
    }
    if failed > 0 {
        return Err(format!("{failed} of {} meshes failed", args.meshes.len()).into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paths(names: &[&str]) -> Vec<PathBuf> {
        names.iter().map(PathBuf::from).collect()
    }

    /// The ids are the daemon's: the digits ending the name, whatever comes before them.
    #[test]
    fn object_ids_follow_the_daemons_rule() {
        let meshes = paths(&["m/obj_000005.ply", "duck7.ply", "part_12.PLY"]);
        assert_eq!(object_ids(&meshes, None).unwrap(), [5, 7, 12]);
        for mesh in &meshes {
            assert_eq!(
                ppfd::ppf_engine::object_id_of_file(mesh),
                Some(object_ids(std::slice::from_ref(mesh), None).unwrap()[0])
            );
        }
        assert_eq!(object_ids(&paths(&["duck.ply"]), Some(3)).unwrap(), [3]);
        assert_eq!(
            object_ids(&paths(&["obj_000001.ply"]), Some(3)).unwrap(),
            [3]
        );
    }

    #[test]
    fn a_mesh_without_an_id_or_with_another_meshs_id_is_refused_by_name() {
        let e = object_ids(&paths(&["duck.ply", "obj_000001.ply"]), None).unwrap_err();
        assert!(
            e.starts_with("duck.ply: no object id") && e.contains("--id"),
            "{e}"
        );
        let e = object_ids(&paths(&["a/part1.ply", "b/obj_000001.ply"]), None).unwrap_err();
        assert!(
            e.starts_with("a/part1.ply and b/obj_000001.ply are both object 1"),
            "{e}"
        );
        let e = object_ids(&paths(&["obj_1.ply", "obj_1.ply"]), None).unwrap_err();
        assert_eq!(e, "obj_1.ply is given twice");
        let e = object_ids(&paths(&["obj_000000.ply"]), None).unwrap_err();
        assert!(e.contains("object id 0"), "{e}");
        let e = object_ids(&paths(&["a1.ply", "b2.ply"]), Some(3)).unwrap_err();
        assert!(e.starts_with("--id applies to a single mesh"), "{e}");
    }

    #[test]
    fn a_folder_is_refused_as_a_folder() {
        let e = object_ids(&[std::env::temp_dir()], Some(1)).unwrap_err();
        assert!(
            e.contains("is a directory") && e.contains("PLY mesh files"),
            "{e}"
        );
    }
}
