//! `ppf detect`: one detect request against a running daemon; prints the poses and the latency
//! breakdown.

use std::path::{Path, PathBuf};

use ppfd_client::{DetectOptions, PoseHint};

use crate::common::{millis, print_hypotheses, print_latency, Connect};

/// What `ppf detect --camera` asks for; the flags are parsed with the dataset form of the command
/// ([`crate::detect_offline::DetectCommand`]).
#[derive(Debug)]
pub struct DetectArgs {
    /// Camera whose newest frame to use.
    pub camera: String,
    /// Object ids.
    pub objects: Vec<u32>,
    /// Hypotheses per object.
    pub hypotheses: u32,
    /// Give up after this long, milliseconds.
    pub timeout_ms: u64,
    /// Print the answer as JSON.
    pub json: bool,
    /// What the poses must satisfy, and their order.
    pub requirements: ppfd_client::Requirements,
    /// Where to write the overlay picture, and the models folder to draw outlines from.
    pub overlay: Option<(PathBuf, PathBuf)>,
    /// A JSON file of poses to refine first.
    pub hints: Option<PathBuf>,
    /// A JSON file of the poses to diagnose against.
    pub diagnose_against: Option<PathBuf>,
    pub connect: Connect,
}

/// The poses of a hints file: the `hypotheses` of `ppf detect --json` output, of which those
/// of `objects` are kept (a whole earlier answer serves any of its objects, as Python's
/// `hints=previous` does), or a list of objects with `object_id`, `rotation` (9 numbers,
/// row-major) and `translation_mm` (3), all kept (a pose of an object not asked for is the
/// daemon's to refuse).
pub fn read_hints(path: &Path, objects: &[u32]) -> Result<Vec<PoseHint>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: not JSON: {e}", path.display()))?;
    let answer = value.get("hypotheses");
    let list = answer.unwrap_or(&value).as_array().ok_or_else(|| {
        format!(
            "{}: expected a list of poses, or an object with a \"hypotheses\" list (ppf \
                 detect --json)",
            path.display()
        )
    })?;
    list.iter()
        .enumerate()
        .map(|(i, entry)| {
            let numbers = |field: &str, n: usize| -> Result<Vec<f32>, String> {
                let bad = || {
                    format!(
                        "{}: pose {i}: \"{field}\" must be a list of {n} numbers",
                        path.display()
                    )
                };
                let values = entry
                    .get(field)
                    .and_then(|v| v.as_array())
                    .ok_or_else(bad)?;
                if values.len() != n {
                    return Err(bad());
                }
                values
                    .iter()
                    .map(|v| v.as_f64().map(|x| x as f32).ok_or_else(bad))
                    .collect()
            };
            let object_id = entry
                .get("object_id")
                .and_then(|v| v.as_u64())
                .and_then(|v| u32::try_from(v).ok())
                .ok_or_else(|| {
                    format!(
                        "{}: pose {i}: \"object_id\" must be an object id",
                        path.display()
                    )
                })?;
            let mut hint = PoseHint {
                object_id,
                ..Default::default()
            };
            hint.rotation.copy_from_slice(&numbers("rotation", 9)?);
            hint.translation_mm
                .copy_from_slice(&numbers("translation_mm", 3)?);
            Ok(hint)
        })
        .filter(|hint| {
            answer.is_none()
                || hint
                    .as_ref()
                    .map_or(true, |h| objects.contains(&h.object_id))
        })
        .collect()
}

pub fn run(args: DetectArgs) -> Result<(), String> {
    let hints = match &args.hints {
        Some(path) => read_hints(path, &args.objects)?,
        None => Vec::new(),
    };
    // A file of a whole scene's poses serves any subset of its objects.
    let diagnose: Vec<PoseHint> = match &args.diagnose_against {
        Some(path) => {
            let poses: Vec<PoseHint> = read_hints(path, &args.objects)?
                .into_iter()
                .filter(|p| args.objects.contains(&p.object_id))
                .collect();
            if poses.is_empty() {
                return Err(format!(
                    "{} has no pose of the objects asked for ({:?}): nothing to diagnose against",
                    path.display(),
                    args.objects
                ));
            }
            poses
        }
        None => Vec::new(),
    };
    // The picture's path and meshes are checked before the detection, not after its work.
    let overlay_meshes = match &args.overlay {
        Some((path, models)) => {
            crate::overlay::check_path(path)?;
            Some(meshes_in(models, &args.objects).map_err(|e| format!("--models: {e}"))?)
        }
        None => None,
    };
    let client = args.connect.client()?;
    // Subscribed before the request, so that the frame the daemon uses arrives here too.
    let recorder = match &args.overlay {
        Some(_) => Some(FrameRecorder::start(args.connect.prefix()?, &args.camera)?),
        None => None,
    };
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: millis(args.timeout_ms),
        requirements: args.requirements,
        hints,
        diagnose,
        ..Default::default()
    };
    let found = crate::common::detect_once_framed(&client, &args.camera, &args.objects, &options)
        .map_err(|e| e.to_string())?;
    print_found(&args, &found)?;
    // After the answer is printed: a picture that cannot be drawn loses none of it.
    if let (Some((path, models)), Some(recorder), Some(meshes)) =
        (&args.overlay, recorder, overlay_meshes)
    {
        let models_info = client.models().map_err(|e| e.to_string())?;
        check_meshes_match(models, &meshes, &models_info)?;
        write_overlay(path, &meshes, &recorder.finish()?, &found)?;
    }
    Ok(())
}

/// Prints the answer: as JSON with `--json`, else as tables.
fn print_found(args: &DetectArgs, found: &ppfd_client::Detections) -> Result<(), String> {
    if args.json {
        let hyps: Vec<serde_json::Value> = found
            .hypotheses
            .iter()
            .map(|h| {
                serde_json::json!({
                    "object_id": h.object_id, "rank": h.instance_rank + 1, "score": h.score, "votes": h.votes,
                    "checks": h.checks, "rotation": h.rotation, "translation_mm": h.translation_mm,
                })
            })
            .collect();
        let l = &found.latency;
        let latency: serde_json::Map<String, serde_json::Value> = crate::common::stages(&l.daemon)
            .iter()
            .map(|stage| (format!("{}_ns", stage.key), stage.ns.into()))
            .chain([
                ("detection_ns".to_owned(), l.daemon.detection_ns.into()),
                ("total_ns".to_owned(), l.daemon.total_ns.into()),
                ("hand_back_ns".to_owned(), l.hand_back_ns().into()),
                (
                    "response_transport_ns".to_owned(),
                    l.response_transport_ns.into(),
                ),
                ("end_to_end_ns".to_owned(), l.end_to_end_ns.into()),
                ("overhead_ns".to_owned(), l.overhead_ns().into()),
            ])
            .collect();
        let mut out = serde_json::json!({
            "request_id": found.request_id, "frame_sequence": found.frame_sequence,
            "frame_age_ns": found.frame_age_ns, "hypotheses": hyps, "latency": latency,
            "counts": { "scene_points": found.counts.scene_points, "reference_points": found.counts.reference_points,
                        "pairs": found.counts.pairs, "hypotheses": found.counts.hypotheses,
                        "returned": found.counts.returned },
        });
        if args.diagnose_against.is_some() {
            out["diagnosis"] = found.diagnosis.lines().collect::<Vec<_>>().into();
        }
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    println!(
        "frame {} ({:.1} ms old): {} scene points, {} reference points, {} pairs",
        found.frame_sequence,
        found.frame_age_ns as f64 / 1e6,
        found.counts.scene_points,
        found.counts.reference_points,
        found.counts.pairs
    );
    print_hypotheses(found, &args.objects);
    if !found.diagnosis.is_empty() {
        println!("\ndiagnosis (against the poses of the --diagnose-against file):");
        print!("{}", found.diagnosis);
    }
    print_latency(found);
    Ok(())
}

/// Refuses meshes that are not the daemon's models of their objects: an outline drawn from
/// another object's mesh would show a wrong pose where the detection found a right one. A
/// mesh whose diameter differs from the daemon's model's by more than 5 % is another mesh.
fn check_meshes_match(
    models: &std::path::Path,
    meshes: &[(u32, ppfd_models::geometry::mesh::Mesh)],
    served: &[ppfd_client::protocol::control::ModelInfo],
) -> Result<(), String> {
    for (id, mesh) in meshes {
        let Some(info) = served.iter().find(|m| m.object_id == *id) else {
            continue;
        };
        let drawn = ppfd_models::model::sampling::diameter(&mesh.positions);
        if (drawn - info.diameter_mm).abs() > 0.05 * info.diameter_mm {
            return Err(format!(
                "--models {}: the mesh of object {id} is {drawn:.1} mm across, the daemon's model \
                 of object {id} {:.1} mm: not the mesh the daemon detects with; give --models the \
                 folder the daemon loaded (no overlay written)",
                models.display(),
                info.diameter_mm
            ));
        }
    }
    Ok(())
}

/// Draws the answer over the frame it was found in (the newest this process received when
/// that one has gone by) and writes the picture.
fn write_overlay(
    path: &std::path::Path,
    meshes: &[(u32, ppfd_models::geometry::mesh::Mesh)],
    frames: &[Frame],
    found: &ppfd_client::Detections,
) -> Result<(), String> {
    let (header, depth) = frames
        .iter()
        .find(|(h, _)| h.sequence == found.frame_sequence)
        .or(frames.last())
        .ok_or("the camera sent this process no frame to draw the overlay on")?;
    if header.sequence != found.frame_sequence {
        eprintln!(
            "note: the overlay shows frame {}, the detection used frame {}",
            header.sequence, found.frame_sequence
        );
    }
    let k = header.intrinsics;
    let frame = ppfd_models::geometry::camera::DepthFrame {
        width: header.width,
        height: header.height,
        intrinsics: ppfd_models::geometry::camera::Intrinsics {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
        },
        depth_scale_mm: header.depth_scale_mm,
        depth,
    };
    crate::overlay::draw_detections(&frame, None, meshes, found, &[]).write_png(path)?;
    // On stderr: stdout may be the JSON answer.
    eprintln!("overlay written to {}", path.display());
    Ok(())
}

/// The meshes of `objects` in the folder `models`, each object's first: a PLY mesh's object is
/// the number its name ends in, a model file's the id it holds, as the daemon takes them.
fn meshes_in(
    models: &std::path::Path,
    objects: &[u32],
) -> Result<Vec<(u32, ppfd_models::geometry::mesh::Mesh)>, String> {
    let mut meshes: Vec<(u32, ppfd_models::geometry::mesh::Mesh)> = Vec::new();
    for entry in std::fs::read_dir(models).map_err(|e| format!("{}: {e}", models.display()))? {
        let file = entry.map_err(|e| e.to_string())?.path();
        let wanted = |id: u32| objects.contains(&id) && !meshes.iter().any(|(m, _)| *m == id);
        let is = |ext: &str| {
            file.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case(ext))
        };
        if is("ply") {
            if let Some(id) = ppfd::ppf_engine::object_id_of_file(&file).filter(|&id| wanted(id)) {
                meshes.push((id, crate::overlay::mesh_of_file(&file)?));
            }
        } else if is(ppfd_models::model::store::EXTENSION) {
            match ppfd_models::model::store::load(&file) {
                Ok(model) if wanted(model.object_id()) => {
                    meshes.push((model.object_id(), model.render_mesh()))
                }
                Ok(_) => {}
                Err(e) => eprintln!("note: {e}: not drawn from"),
            }
        }
    }
    if let Some(missing) = objects
        .iter()
        .find(|id| !meshes.iter().any(|(m, _)| m == *id))
    {
        return Err(format!(
            "{} holds no mesh or model file of object {missing} to draw",
            models.display()
        ));
    }
    Ok(meshes)
}

/// A camera frame as received: its header and depth.
type Frame = (ppfd_client::FrameHeader, Vec<u16>);

/// Receives a camera's frames on a thread of its own while the request runs, keeping the newest
/// [`FrameRecorder::KEPT`] (fewer when they would take more than [`FrameRecorder::KEPT_BYTES`]).
/// The camera queues two frames per reader, and a detection outlasts two frames of a camera at
/// 10 frames per second or more: read only after the answer, the frame the daemon used would be
/// gone.
struct FrameRecorder {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<Result<Vec<Frame>, String>>,
}

impl FrameRecorder {
    /// Frames kept: a second of a 30 frames-per-second camera, 18 MB of VGA depth.
    const KEPT: usize = 30;
    /// ... and at most this many bytes of depth (but always the newest two frames): three 4K
    /// frames.
    const KEPT_BYTES: usize = 64 << 20;

    /// Subscribes to `camera` (an iceoryx2 subscriber is not `Send`, so the thread opens it)
    /// and returns once subscribed.
    fn start(prefix: Option<String>, camera: &str) -> Result<FrameRecorder, String> {
        use std::sync::atomic::Ordering;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (ready, subscribed) = std::sync::mpsc::channel();
        let (stopping, camera) = (stop.clone(), camera.to_owned());
        let thread = std::thread::spawn(move || {
            let viewer = match ppfd_client::CameraViewer::open(prefix.as_deref(), &camera) {
                Ok(viewer) => {
                    let _ = ready.send(Ok(()));
                    viewer
                }
                Err(e) => {
                    let _ = ready.send(Err(e.to_string()));
                    return Ok(Vec::new());
                }
            };
            let mut kept: std::collections::VecDeque<Frame> =
                std::collections::VecDeque::with_capacity(Self::KEPT + 1);
            let mut bytes = 0;
            loop {
                // Read once more after the stop is seen: the frames sent meanwhile count too.
                let last = stopping.load(Ordering::Acquire);
                for frame in viewer.frames().map_err(|e| e.to_string())? {
                    bytes += 2 * frame.1.len();
                    kept.push_back(frame);
                    while kept.len() > Self::KEPT || (bytes > Self::KEPT_BYTES && kept.len() > 2) {
                        let (_, depth) = kept.pop_front().expect("more than two frames kept");
                        bytes -= 2 * depth.len();
                    }
                }
                if last {
                    return Ok(kept.into());
                }
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        });
        match subscribed.recv() {
            Ok(Ok(())) => Ok(FrameRecorder { stop, thread }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err("the thread reading the camera's frames ended".into()),
        }
    }

    /// Stops reading; the frames kept, oldest first.
    fn finish(self) -> Result<Vec<Frame>, String> {
        self.stop.store(true, std::sync::atomic::Ordering::Release);
        self.thread
            .join()
            .map_err(|_| "the thread reading the camera's frames panicked".to_string())?
    }
}

#[cfg(test)]
mod tests {
    use ppfd_models::synthetic::parts::Part;

    /// A whole earlier answer (`--json`) serves any of its objects: the poses of objects not
    /// asked for are left out. A list written by hand is taken whole, for the daemon to judge.
    #[test]
    fn an_answer_gives_the_hints_of_the_objects_asked_for() {
        let dir = std::env::temp_dir().join(format!("ppf-hints-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pose = |id: u32| {
            serde_json::json!({"object_id": id, "rank": 1, "score": 0.5,
                "rotation": [1, 0, 0, 0, 1, 0, 0, 0, 1], "translation_mm": [0, 0, 800]})
        };
        let answer = dir.join("answer.json");
        let list = serde_json::json!([pose(1), pose(2), pose(1)]);
        std::fs::write(&answer, serde_json::json!({"hypotheses": list}).to_string()).unwrap();
        let hand = dir.join("hand.json");
        std::fs::write(&hand, list.to_string()).unwrap();
        let ids = |path, objects: &[u32]| -> Vec<u32> {
            let hints = super::read_hints(path, objects).unwrap();
            hints.iter().map(|h| h.object_id).collect()
        };
        assert_eq!(ids(&answer, &[1]), [1, 1]);
        assert_eq!(ids(&answer, &[2, 5]), [2]);
        assert_eq!(ids(&hand, &[1]), [1, 2, 1]);
        assert_eq!(
            super::read_hints(&answer, &[1]).unwrap()[0].translation_mm,
            [0.0, 0.0, 800.0]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A model file is drawn as the object it holds, whatever its name says.
    #[test]
    fn a_model_file_is_drawn_as_the_object_it_holds() {
        let dir = std::env::temp_dir().join(format!("ppf-meshes-in-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let model = Part::TPipe.model().unwrap();
        let id = model.object_id();
        ppfd_models::model::store::save(&model, &dir.join("pipe.PPFM")).unwrap();
        ppfd_models::model::store::save(&model, &dir.join(format!("obj_{}.ppfm", id + 1))).unwrap();
        let found = super::meshes_in(&dir, &[id]).unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].0, id);
        assert!(!found[0].1.faces.is_empty());
        let e = super::meshes_in(&dir, &[id + 1]).unwrap_err();
        assert!(
            e.contains(&format!("no mesh or model file of object {}", id + 1)),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
