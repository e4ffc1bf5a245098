//! `ppf model`: build model files from meshes, show what one holds, and benchmark building and
//! loading.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ppfd_models::mesh::Mesh;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::store;

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
    /// PLY meshes, in millimetres. A file named `obj_000005.ply` gets object id 5; others are
    /// numbered in the order given, from 1, unless `--id` is set.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Directory to write the model files into.
    #[arg(long)]
    pub out: PathBuf,
    /// Object id for a single mesh.
    #[arg(long)]
    pub id: Option<u32>,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// PLY meshes to build.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Repetitions per model; the table shows medians.
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
}

/// The object id a BOP-style file name implies (`obj_000005.ply` → 5).
pub fn object_id_from_path(path: &Path) -> Option<u32> {
    let stem = path.file_stem()?.to_str()?;
    stem.strip_prefix("obj_")?.parse().ok()
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
    if args.id.is_some() && args.meshes.len() > 1 {
        return Err(
            "--id applies to a single mesh; BOP file names (obj_NNNNNN.ply) give ids".into(),
        );
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
    let bar = ProgressBar::new(args.meshes.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} [{elapsed}]").unwrap());
    let params = ModelParams::default();
    let mut failures = 0;
    for (i, path) in args.meshes.iter().enumerate() {
        let id = args
            .id
            .or_else(|| object_id_from_path(path))
            .unwrap_or(i as u32 + 1);
        let name = name_of(path);
        bar.set_message(name.clone());
        let result = Mesh::from_ply_file(path)
            .and_then(|mesh| ObjectModel::build(&mesh, id, &name, &params))
            .and_then(|model| {
                let out = args.out.join(format!("{name}.{}", store::EXTENSION));
                store::save(&model, &out).map(|_| (model, out))
            });
        match result {
            // `suspend`, not `ProgressBar::println`: that prints nothing when the bar is
            // hidden (output not a terminal), and a script would see no reason for a failure.
            Ok((model, out)) => bar.suspend(|| {
                println!(
                    "{}: object {id}, {} points, {} table entries, {:.1} MB -> {}",
                    path.display(),
                    model.point_count(),
                    model.table_entry_count(),
                    model.byte_size() as f64 / 1e6,
                    out.display()
                )
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
    println!("diameter        {:.3} mm", model.diameter_mm());
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
    let mesh = model.render_mesh();
    println!(
        "mesh            {} vertices, {} triangles, fingerprint {:08x}",
        mesh.positions.len(),
        mesh.faces.len(),
        model.mesh_fingerprint()
    );
    println!("size            {:.2} MB", model.byte_size() as f64 / 1e6);
    println!("parameters      {p:?}");
    Ok(())
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn bench(args: BenchArgs) -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join(format!("ppf-model-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let repeat = args.repeat.max(1);
    println!("| model | build (ms) | points | table entries | size (MB) | load (ms) | D (mm) |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let params = ModelParams::default();
    for (i, path) in args.meshes.iter().enumerate() {
        let mesh = Mesh::from_ply_file(path)?;
        let id = object_id_from_path(path).unwrap_or(i as u32 + 1);
        let name = name_of(path);
        let mut builds = Vec::new();
        let mut model = None;
        for _ in 0..repeat {
            let t = Instant::now();
            model = Some(ObjectModel::build(&mesh, id, &name, &params)?);
            builds.push(t.elapsed());
        }
        let model = model.unwrap();
        let file = dir.join(format!("{name}.{}", store::EXTENSION));
        store::save(&model, &file)?;
        let mut loads = Vec::new();
        for _ in 0..repeat {
            let t = Instant::now();
            let loaded = store::load(&file)?;
            loads.push(t.elapsed());
            assert_eq!(loaded.table_entry_count(), model.table_entry_count());
        }
        println!(
            "| {name} | {:.0} | {} | {} | {:.2} | {:.2} | {:.2} |",
            median(builds).as_secs_f64() * 1e3,
            model.point_count(),
            model.table_entry_count(),
            model.byte_size() as f64 / 1e6,
            median(loads).as_secs_f64() * 1e3,
            model.diameter_mm()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
