//! End to end with the real engine: the daemon builds models from the LM-O meshes, a camera
//! process publishes a synthetic frame with ground truth, and a client gets a pose that matches it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use ppfd_models::bop::BopDataset;
use ppfd_tests::{Prefix, Proc};

const DAEMON: &str = env!("CARGO_BIN_EXE_e2e-daemon");
const CAMERA: &str = env!("CARGO_BIN_EXE_e2e-camera");

fn dataset_root() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/synth-lmo-dev");
    if root.is_dir() {
        return Some(root);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!(
            "{} is missing and CI=true: the test data must be there",
            root.display()
        );
    }
    eprintln!("skipping: {} not found", root.display());
    None
}

#[test]
fn poses_through_the_whole_path_match_the_ground_truth() {
    let Some(root) = dataset_root() else { return };
    let dataset = BopDataset::open(&root).unwrap();
    let (scene, image) = (dataset.scene_ids()[0], 0);
    let image = dataset
        .image_ids(scene)
        .unwrap()
        .first()
        .copied()
        .unwrap_or(image);
    let truth = dataset.ground_truth(scene, image).unwrap().to_vec();
    let info = dataset.ground_truth_info(scene, image).unwrap().to_vec();
    // The well visible objects: a depth-only method cannot be asked to find a sliver.
    let wanted: Vec<(u32, ppfd_models::Pose, f32)> = truth
        .iter()
        .zip(&info)
        .filter(|(_, i)| i.visib_fract >= 0.6)
        .map(|(g, _)| {
            (
                g.obj_id,
                g.pose,
                dataset.model_info(g.obj_id).unwrap().diameter_mm,
            )
        })
        .take(1)
        .collect();
    assert!(
        !wanted.is_empty(),
        "scene {scene} image {image} has no well visible object"
    );

    let prefix = Prefix::new("poses");
    let work = std::env::temp_dir().join(format!("ppfd-e2e-poses-{}", std::process::id()));
    let models = work.join("models");
    let cache = work.join("cache");
    std::fs::create_dir_all(&models).unwrap();
    for (id, _, _) in &wanted {
        let mesh = std::fs::canonicalize(dataset.model_path(*id).unwrap()).unwrap();
        std::os::unix::fs::symlink(&mesh, models.join(mesh.file_name().unwrap())).unwrap();
    }
    let mut d = Proc::spawn(
        Path::new(DAEMON),
        &[
            "--prefix",
            &prefix.0,
            "--models",
            models.to_str().unwrap(),
            "--model-cache",
            cache.to_str().unwrap(),
            "--housekeeping-ms",
            "100",
            "--max-frame-age-ms",
            "5000",
        ],
        &[],
    );
    d.wait_line("ppfd ready", Duration::from_secs(600));
    let (scene_s, image_s) = (scene.to_string(), image.to_string());
    let mut cam = Proc::spawn(
        Path::new(CAMERA),
        &[
            "--prefix",
            &prefix.0,
            "--camera",
            "synth",
            "--fps",
            "5",
            "--bop",
            root.to_str().unwrap(),
            "--scene",
            &scene_s,
            "--image",
            &image_s,
        ],
        &[],
    );
    cam.wait_line("camera ready", Duration::from_secs(20));
    cam.wait_line("frame 2", Duration::from_secs(20));

    let ids: Vec<u32> = wanted.iter().map(|w| w.0).collect();
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap();
    let options = ppfd_client::DetectOptions {
        hypotheses_per_object: 3,
        timeout: Duration::from_secs(600),
        ..Default::default()
    };
    let found = client.detect("synth", &ids, &options).expect("detections");
    eprintln!("latency: {:?}", found.latency);
    for (id, truth, diameter) in &wanted {
        let best = found
            .best(*id)
            .unwrap_or_else(|| panic!("no hypothesis for object {id}"));
        let pose = ppfd_client::isometry(best);
        let dt = (pose.translation.vector - truth.translation.vector).norm();
        let dr = pose.rotation.angle_to(&truth.rotation).to_degrees();
        eprintln!(
            "object {id}: dt {dt:.1} mm, dR {dr:.1} deg, score {:.3}",
            best.score
        );
        // Translation within a tenth of the diameter; rotation loosely (symmetric objects).
        assert!(
            dt < 0.1 * diameter,
            "object {id}: translation off by {dt:.1} mm (diameter {diameter:.0})"
        );
    }
    assert!(
        found.latency.daemon.detection_ns > 0
            && found.latency.end_to_end_ns >= found.latency.daemon.detection_ns
    );
    assert!(
        found.counts.scene_points > 0 && found.counts.pairs > 0,
        "{:?}",
        found.counts
    );

    let _ = std::fs::remove_dir_all(&work);
}
