//! Fuzzing with mutated and random input: the PLY reader, the BOP dataset readers, the model
//! file loader, the daemon's configuration, and the daemon's detect and control requests through
//! the real service. Nothing may panic; every input gets an error that names what it read, or a
//! result that holds up (a mesh that validates, a model that detects, a daemon that still
//! serves). Each target runs a short pass here and a long one with `--ignored` (minutes):
//!
//! ```text
//! cargo test -p ppfd-tests --test fuzz -- --ignored --nocapture
//! ```
//!
//! Both print how many inputs they tried; `PPFD_FUZZ_CASES=N` sets the count.

use std::path::Path;
use std::time::Duration;

use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

use ppfd::config::DaemonConfig;
use ppfd_bop::dataset::BopDataset;
use ppfd_models::detect::detector::{Detector, RunOptions};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::{store, ObjectModel};
use ppfd_models::synthetic::parts::Part;
use ppfd_tests::fuzz::{cases, edits, mutate, run, Edit, LONG_CASES, SHORT_CASES};
use ppfd_tests::{fake_model_dir, part_model, parts_scene, Prefix, WorkDir};

mod common;
use common::{camera, fake_daemon};

/// Fails the case unless `cond`, with `msg`.
fn ensure(cond: bool, msg: impl FnOnce() -> String) -> Result<(), TestCaseError> {
    if cond {
        Ok(())
    } else {
        Err(TestCaseError::fail(msg()))
    }
}

// ---------------------------------------------------------------------------------------------
// PLY

/// A generated part as binary little-endian PLY: positions as floats, triangles as uchar/int
/// lists.
fn binary_ply(mesh: &Mesh) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.faces.len()
    )
    .into_bytes();
    for p in &mesh.positions {
        for c in [p.x, p.y, p.z] {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for f in &mesh.faces {
        out.push(3);
        for i in f {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

fn fuzz_ply(n: u32) {
    let mesh = Part::LBracket.mesh();
    let bases = [mesh.to_ply_ascii().into_bytes(), binary_ply(&mesh)];
    for base in &bases {
        let read = Mesh::from_ply_reader(&base[..], "part.ply").expect("the base PLY reads");
        assert_eq!(read.faces.len(), mesh.faces.len());
    }
    run("PLY reader", n, (0..bases.len(), edits()), |(b, e)| {
        let bytes = mutate(&bases[b], &e);
        match Mesh::from_ply_reader(&bytes[..], "part.ply") {
            // A mesh read is a mesh the rest of the library can take.
            Ok(m) => ensure(m.validate().is_ok(), || {
                format!("read an invalid mesh: {:?}", m.validate())
            }),
            Err(err) => ensure(err.to_string().contains("part.ply"), || {
                format!("the error does not name the file: {err}")
            }),
        }
    });
}

#[test]
fn the_ply_reader_refuses_mutated_meshes_or_reads_valid_ones() {
    fuzz_ply(cases(SHORT_CASES));
}

#[test]
#[ignore = "the long fuzzing run (minutes): cargo test -p ppfd-tests --test fuzz -- --ignored"]
fn the_ply_reader_refuses_mutated_meshes_or_reads_valid_ones_long() {
    fuzz_ply(cases(LONG_CASES));
}

// ---------------------------------------------------------------------------------------------
// BOP datasets

/// The files of a small dataset in the BOP layout: one scene with two annotated images.
fn dataset_files() -> Vec<(&'static str, String)> {
    let k = "[572.4, 0.0, 325.3, 0.0, 573.6, 242.0, 0.0, 0.0, 1.0]";
    let gt = |id: u32, z: f32| {
        format!(
            "{{\"cam_R_m2c\": [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0], \"cam_t_m2c\": [10.0, -20.0, {z}], \"obj_id\": {id}}}"
        )
    };
    let info = "{\"bbox_obj\": [10, 20, 30, 40], \"bbox_visib\": [10, 20, 30, 40], \"px_count_all\": 900, \"px_count_valid\": 880, \"px_count_visib\": 700, \"visib_fract\": 0.78}";
    vec![
        (
            "camera.json",
            "{\"cx\": 325.3, \"cy\": 242.0, \"depth_scale\": 1.0, \"fx\": 572.4, \"fy\": 573.6, \"height\": 480, \"width\": 640}".into(),
        ),
        (
            "models/models_info.json",
            "{\"1\": {\"diameter\": 102.1, \"min_x\": -37.9, \"min_y\": -38.8, \"min_z\": -45.9, \"size_x\": 75.9, \"size_y\": 77.6, \"size_z\": 91.8}, \"2\": {\"diameter\": 201.4, \"min_x\": -50.4, \"min_y\": -90.9, \"min_z\": -96.9, \"size_x\": 100.8, \"size_y\": 181.8, \"size_z\": 193.7, \"symmetries_discrete\": [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}}".into(),
        ),
        (
            "test_targets_bop19.json",
            "[{\"im_id\": 3, \"inst_count\": 1, \"obj_id\": 1, \"scene_id\": 1}, {\"im_id\": 4, \"inst_count\": 1, \"obj_id\": 2, \"scene_id\": 1}]".into(),
        ),
        (
            "test/000001/scene_camera.json",
            format!("{{\"3\": {{\"cam_K\": {k}, \"depth_scale\": 1.0}}, \"4\": {{\"cam_K\": {k}, \"depth_scale\": 0.1}}}}"),
        ),
        (
            "test/000001/scene_gt.json",
            format!("{{\"3\": [{}, {}], \"4\": [{}]}}", gt(1, 900.0), gt(2, 1100.0), gt(2, 1000.0)),
        ),
        (
            "test/000001/scene_gt_info.json",
            format!("{{\"3\": [{info}, {info}], \"4\": [{info}]}}"),
        ),
    ]
}

fn write_dataset(root: &Path, files: &[(&str, String)]) {
    for (name, text) in files {
        let path = root.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }
}

/// Everything the readers can be asked of the dataset at `root`; the first error, if any.
fn read_everything(root: &Path) -> Result<usize, ppfd_bop::Error> {
    let d = BopDataset::open(root)?;
    let mut read = 0;
    for id in d.object_ids().to_vec() {
        d.model_info(id)?;
        read += 1;
    }
    d.test_targets();
    for scene in d.scene_ids() {
        for im in d.image_ids(scene)? {
            d.scene_camera(scene, im)?;
            read += d.ground_truth(scene, im)?.len();
            read += d.ground_truth_info(scene, im)?.len();
        }
    }
    Ok(read)
}

fn fuzz_dataset(n: u32) {
    let files = dataset_files();
    let dir = WorkDir::new("fuzz-dataset");
    write_dataset(&dir, &files);
    // 2 models, 3 instances and their 3 infos.
    assert_eq!(read_everything(&dir).expect("the base dataset reads"), 8);
    run(
        "BOP dataset readers",
        n,
        (0..files.len(), edits()),
        |(f, e)| {
            let root = dir.join("d");
            let _ = std::fs::remove_dir_all(&root);
            let mut mutated = files.clone();
            let bytes = mutate(files[f].1.as_bytes(), &e);
            mutated[f].1 = String::from_utf8_lossy(&bytes).into_owned();
            write_dataset(&root, &mutated);
            match read_everything(&root) {
                Ok(_) => Ok(()),
                // The error names the file it could not take (or the folder, for the layout).
                Err(err) => {
                    let file = Path::new(files[f].0).file_name().unwrap().to_str().unwrap();
                    let text = err.to_string();
                    ensure(text.contains(file) || text.contains("/d"), || {
                        format!("the error names neither {file} nor the dataset: {text}")
                    })
                }
            }
        },
    );
}

#[test]
fn the_dataset_readers_refuse_mutated_json_with_the_file_named() {
    fuzz_dataset(cases(SHORT_CASES));
}

#[test]
#[ignore = "the long fuzzing run (minutes): cargo test -p ppfd-tests --test fuzz -- --ignored"]
fn the_dataset_readers_refuse_mutated_json_with_the_file_named_long() {
    fuzz_dataset(cases(LONG_CASES));
}

// ---------------------------------------------------------------------------------------------
// Model files

/// Where a model file's payload starts and where its header keeps the payload's CRC-32.
const MODEL_HEADER_LEN: usize = 32;
const MODEL_CRC_AT: usize = 24;

fn fuzz_model_file(n: u32) {
    let dir = WorkDir::new("fuzz-model");
    let model = part_model(Part::LBracket);
    let path = dir.join("base.ppfm");
    store::save(&model, &path).unwrap();
    let base = std::fs::read(&path).unwrap();
    let scene = parts_scene(5, false);
    let detector = Detector::default();
    let opts = RunOptions {
        hypotheses_per_object: 1,
        ..Default::default()
    };
    let detect = |m: &ObjectModel| detector.detect(&scene.frame.view(), &[m], &opts);
    detect(&store::load(&path).unwrap()).expect("the base model detects");
    let target = dir.join("mutated.ppfm");
    // Half the cases keep the checksum right, so that the mutation reaches the payload's
    // validation instead of stopping at the checksum.
    run(
        "model file loader",
        n,
        (edits(), any::<bool>()),
        |(e, fix_crc)| {
            let mut bytes = mutate(&base, &e);
            if fix_crc && bytes.len() >= MODEL_HEADER_LEN {
                let crc = crc32fast::hash(&bytes[MODEL_HEADER_LEN..]);
                bytes[MODEL_CRC_AT..MODEL_CRC_AT + 4].copy_from_slice(&crc.to_le_bytes());
            }
            std::fs::write(&target, &bytes).unwrap();
            match store::load(&target) {
                // A model the loader takes must be one the detector can run on.
                Ok(m) => match detect(&m) {
                    Ok(_) => Ok(()),
                    Err(err) => ensure(!err.to_string().is_empty(), || "an empty error".into()),
                },
                Err(err) => ensure(err.to_string().contains("mutated.ppfm"), || {
                    format!("the error does not name the file: {err}")
                }),
            }
        },
    );
}

#[test]
fn the_model_loader_refuses_mutated_files_or_loads_models_that_detect() {
    fuzz_model_file(cases(SHORT_CASES / 3));
}

#[test]
#[ignore = "the long fuzzing run (minutes): cargo test -p ppfd-tests --test fuzz -- --ignored"]
fn the_model_loader_refuses_mutated_files_or_loads_models_that_detect_long() {
    fuzz_model_file(cases(LONG_CASES / 10));
}

// ---------------------------------------------------------------------------------------------
// The daemon's configuration

const CONFIG: &str = "models = \"models\"
model_cache = \"cache\"
prefix = \"cell2_\"
workers = 2
parallel_detections = 1
queue_capacity = 64
max_frame_age_ms = 1000
housekeeping_ms = 1000
forget_camera_after_ms = 60000

[detector]
voting.reference_step = 2
filters.min_silhouette_fraction = 0.5
scene.min_depth_mm = 200
";

fn fuzz_config(n: u32) {
    let base = DaemonConfig::from_toml(CONFIG).expect("the base configuration parses");
    base.validate().expect("the base configuration is valid");
    base.detect_params().expect("its detector table applies");
    run("configuration", n, edits(), |e| {
        let text = String::from_utf8_lossy(&mutate(CONFIG.as_bytes(), &e)).into_owned();
        if let Ok(c) = DaemonConfig::from_toml(&text) {
            // What parses is either refused by the checks, with a message, or usable.
            if let Err(err) = c.validate().and_then(|_| c.detect_params().map(|_| ())) {
                return ensure(!err.to_string().is_empty(), || "an empty error".into());
            }
            ensure(c.worker_threads() >= 1, || {
                format!("{} workers", c.worker_threads())
            })?;
        }
        Ok(())
    });
}

#[test]
fn the_configuration_parser_refuses_mutated_files_or_gives_a_usable_one() {
    fuzz_config(cases(SHORT_CASES));
}

#[test]
#[ignore = "the long fuzzing run (minutes): cargo test -p ppfd-tests --test fuzz -- --ignored"]
fn the_configuration_parser_refuses_mutated_files_or_gives_a_usable_one_long() {
    fuzz_config(cases(LONG_CASES));
}

// ---------------------------------------------------------------------------------------------
// The daemon's requests

/// A detect request's fields, each either valid or hostile, and a payload whose length may
/// disagree with the inline frame's header.
#[derive(Clone, Debug)]
struct DetectInput {
    version_off: Option<u32>,
    flags: u32,
    camera: Vec<u8>,
    width: u32,
    height: u32,
    intrinsics: [f32; 4],
    depth_scale: f32,
    capture_age_ns: i64,
    object_count: u32,
    hypotheses: u32,
    object_ids: Vec<u32>,
    payload_len: usize,
    depth: u16,
    max_frame_age_ns: u64,
}

fn hostile_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => 1.0f32..2000.0,
        1 => Just(0.0f32),
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(-1.0f32),
        1 => any::<f32>(),
    ]
}

fn detect_input() -> impl Strategy<Value = DetectInput> {
    let camera = prop_oneof![
        3 => Just(b"cam0".to_vec()),
        1 => prop::collection::vec(any::<u8>(), 0..40),
    ];
    let dims = prop_oneof![
        2 => Just((64u32, 48u32)),
        1 => (0u32..200, 0u32..200),
        1 => (any::<u32>(), any::<u32>()),
    ];
    (
        (
            prop::option::weighted(0.1, 1u32..u32::MAX),
            prop_oneof![3 => Just(0u32), 2 => Just(1u32), 1 => any::<u32>()],
            camera,
            dims,
            prop::array::uniform4(hostile_f32()),
            hostile_f32(),
            prop_oneof![3 => Just(0i64), 1 => any::<i64>()],
        ),
        (
            prop_oneof![3 => 1u32..4, 1 => any::<u32>()],
            prop_oneof![3 => 1u32..3, 1 => any::<u32>()],
            prop::collection::vec(prop_oneof![3 => 1u32..3, 1 => any::<u32>()], 0..40),
            prop_oneof![2 => Just(usize::MAX), 1 => 0usize..20_000],
            any::<u16>(),
            prop_oneof![3 => Just(0u64), 1 => any::<u64>()],
        ),
    )
        .prop_map(
            |(
                (
                    version_off,
                    flags,
                    camera,
                    (width, height),
                    intrinsics,
                    depth_scale,
                    capture_age_ns,
                ),
                (object_count, hypotheses, object_ids, payload_len, depth, max_frame_age_ns),
            )| DetectInput {
                version_off,
                flags,
                camera,
                width,
                height,
                intrinsics,
                depth_scale,
                capture_age_ns,
                object_count,
                hypotheses,
                object_ids,
                payload_len,
                depth,
                max_frame_age_ns,
            },
        )
}

/// A control request: any command code (the four commands and unknown ones), any object id but
/// those the fuzzing checks serve with (1 and 2), and a path that is empty, missing, not a
/// model, a folder, or random bytes.
#[derive(Clone, Debug)]
struct ControlInput {
    version_off: Option<u32>,
    command: u32,
    object_id: u32,
    path: Vec<u8>,
    reserved: u32,
}

fn control_input() -> impl Strategy<Value = ControlInput> {
    let path = prop_oneof![
        Just(Vec::new()),
        Just(b"/nonexistent/obj_000001.ply".to_vec()),
        Just(b"/etc/hostname".to_vec()),
        Just(b"/tmp".to_vec()),
        Just(b"relative/model.ppfm".to_vec()),
        prop::collection::vec(any::<u8>(), 0..300),
    ];
    (
        prop::option::weighted(0.1, 1u32..u32::MAX),
        prop_oneof![4 => 1u32..=4, 1 => any::<u32>()],
        prop_oneof![any::<u32>().prop_map(|id| id.max(3)), Just(0u32)],
        path,
        prop_oneof![3 => Just(0u32), 1 => any::<u32>()],
    )
        .prop_map(
            |(version_off, command, object_id, path, reserved)| ControlInput {
                version_off,
                command,
                object_id,
                path,
                reserved,
            },
        )
}

fn fuzz_requests(n: u32) {
    use ppfd_client::protocol::control::ControlRequest;
    use ppfd_client::protocol::detect::DetectRequestHeader;
    use ppfd_client::protocol::{clock, PROTOCOL_VERSION};
    use ppfd_client::{DetectOptions, FrameHeader, Intrinsics};

    let prefix = Prefix::new("fuzz");
    let models = fake_model_dir("fuzz-requests", &[1, 2]);
    let mut daemon = fake_daemon(&prefix, &models, &[], &[]);
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .expect("connected");
    let timeout = Duration::from_secs(5);
    let serves = |client: &ppfd_client::Client| {
        client
            .detect("cam0", &[1, 2], &DetectOptions::default())
            .map(|d| d.hypotheses.len())
    };
    assert_eq!(serves(&client).expect("served before fuzzing"), 2);

    let input = prop_oneof![detect_input().prop_map(Ok), control_input().prop_map(Err),];
    run("daemon requests", n, input, |input| {
        match input {
            Ok(d) => {
                let mut h = DetectRequestHeader {
                    flags: d.flags,
                    object_count: d.object_count,
                    hypotheses_per_object: d.hypotheses,
                    max_frame_age_ns: d.max_frame_age_ns,
                    ..Default::default()
                };
                if let Some(v) = d.version_off {
                    h.protocol_version = PROTOCOL_VERSION.wrapping_add(v);
                }
                let name_len = d.camera.len().min(h.camera_name.len());
                h.camera_name[..name_len].copy_from_slice(&d.camera[..name_len]);
                for (slot, id) in h.object_ids.iter_mut().zip(&d.object_ids) {
                    *slot = *id;
                }
                let [fx, fy, cx, cy] = d.intrinsics;
                h.inline_frame = FrameHeader {
                    width: d.width,
                    height: d.height,
                    intrinsics: Intrinsics { fx, fy, cx, cy },
                    depth_scale_mm: d.depth_scale,
                    capture_time_ns: clock::monotonic_now_ns()
                        .saturating_add_signed(d.capture_age_ns),
                    ..Default::default()
                };
                // The frame's own size, or a length that disagrees with it.
                let pixels = (d.width as u64 * d.height as u64).min(1 << 16) as usize;
                let len = if d.payload_len == usize::MAX {
                    pixels
                } else {
                    d.payload_len
                };
                let depth = vec![d.depth; len];
                // Served or refused: both are answers; what matters is that one comes.
                match client.send_raw(&h, &depth, timeout) {
                    Ok(_) => Ok(()),
                    Err(ppfd_client::Error::Refused { message, .. }) => {
                        ensure(!message.is_empty(), || "a refusal without a message".into())
                    }
                    Err(e) => Err(TestCaseError::fail(format!("no answer: {e}"))),
                }
            }
            Err(c) => {
                let mut r = ControlRequest {
                    command: c.command,
                    object_id: c.object_id,
                    reserved: c.reserved,
                    ..Default::default()
                };
                if let Some(v) = c.version_off {
                    r.protocol_version = PROTOCOL_VERSION.wrapping_add(v);
                }
                let n = c.path.len().min(r.path.len());
                r.path[..n].copy_from_slice(&c.path[..n]);
                match client.send_raw_control(&r, timeout) {
                    Ok(_) => Ok(()),
                    Err(ppfd_client::Error::Refused { message, .. }) => {
                        ensure(!message.is_empty(), || "a refusal without a message".into())
                    }
                    Err(e) => Err(TestCaseError::fail(format!("no answer: {e}"))),
                }
            }
        }
    });
    assert_eq!(
        serves(&client).expect("the daemon still serves after the fuzzing"),
        2
    );
    assert!(
        daemon.child.try_wait().unwrap().is_none(),
        "the daemon is still running"
    );
}

#[test]
fn the_daemon_answers_mutated_requests_and_keeps_serving() {
    fuzz_requests(cases(SHORT_CASES));
}

#[test]
#[ignore = "the long fuzzing run (minutes): cargo test -p ppfd-tests --test fuzz -- --ignored"]
fn the_daemon_answers_mutated_requests_and_keeps_serving_long() {
    fuzz_requests(cases(LONG_CASES / 3));
}

/// The edits this file's targets are fed stay meaningful: a few of them applied to a PLY
/// change it.
#[test]
fn mutations_change_the_input() {
    let base = Part::LBracket.mesh().to_ply_ascii().into_bytes();
    assert_ne!(mutate(&base, &[Edit::Token(1 << 31, 6)]), base);
}
