//! Model building on the real LM-O models (`../shared/data/lmo`): every model builds, its
//! diameter agrees with BOP's `models_info.json`, and it survives the store; the symmetric ones
//! keep their symmetry, and one is detected through it.

use ppfd_bop::dataset::BopDataset;
use ppfd_bop::shared_test_data;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};

#[test]
fn lmo_models_build_with_bop_diameters_and_round_trip() {
    let Some(dir) = shared_test_data("lmo") else {
        return;
    };
    let dataset = BopDataset::open(&dir).unwrap();
    let out = std::env::temp_dir().join(format!("ppfd-lmo-models-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    assert_eq!(dataset.object_ids().len(), 8);
    for &id in dataset.object_ids() {
        let mesh = Mesh::from_ply_file(dataset.model_path(id).unwrap()).unwrap();
        let model = ObjectModel::build(&mesh, id, &format!("obj_{id:06}"), &ModelParams::default())
            .unwrap();
        let expected = dataset.model_info(id).unwrap().diameter_mm;
        let rel = (model.diameter_mm() - expected).abs() / expected;
        eprintln!(
            "object {id}: D {:.2} mm (BOP {expected:.2}), {} points, {} entries",
            model.diameter_mm(),
            model.point_count(),
            model.table_entry_count()
        );
        assert!(
            rel < 0.01,
            "object {id}: diameter {} vs {expected}",
            model.diameter_mm()
        );
        let n = model.point_count();
        assert_eq!(model.table_entry_count(), n * (n - 1));
        assert!(
            model.byte_size() < 16_000_000,
            "object {id}: {} bytes",
            model.byte_size()
        );
        let path = out.join(format!("obj_{id}.{}", store::EXTENSION));
        store::save(&model, &path).unwrap();
        let loaded = store::load(&path).unwrap();
        assert_eq!(loaded.table(), model.table());
        assert_eq!(loaded.object_id(), id);
    }
    std::fs::remove_dir_all(out).unwrap();
}

/// The LM-O egg box (10) and glue (11) carry a half turn in `models_info.json`: their models
/// take it, hold it through the store, and refuse a quarter turn, which they do not have.
#[test]
fn lmo_symmetric_objects_keep_their_symmetry_and_refuse_a_false_one() {
    use ppfd_models::model::symmetry::Symmetry;
    let Some(dir) = shared_test_data("lmo") else {
        return;
    };
    let dataset = BopDataset::open(&dir).unwrap();
    let out = std::env::temp_dir().join(format!("ppfd-lmo-symmetry-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    for id in [10, 11] {
        let symmetry = dataset.symmetry(id).unwrap();
        assert_eq!(symmetry.order(), Some(2), "object {id}");
        let mesh = Mesh::from_ply_file(dataset.model_path(id).unwrap()).unwrap();
        let name = format!("obj_{id:06}");
        let model = ObjectModel::build(&mesh, id, &name, &ModelParams::default()).unwrap();
        let d = model.diameter_mm();
        for (what, off) in symmetry.misfits(&model.surface_points()) {
            eprintln!("object {id}: {what}: {off:.2} mm ({:.3} D)", off / d);
        }
        let wrong = Symmetry::generated(&["z:4".parse().unwrap()]).unwrap();
        let refused = ObjectModel::build(&mesh, id, &name, &ModelParams::default())
            .unwrap()
            .with_symmetry(&wrong)
            .unwrap_err()
            .to_string();
        assert!(refused.contains("does not have it"), "{refused}");
        let model = model.with_symmetry(&symmetry).unwrap();
        let path = out.join(format!("{name}.{}", store::EXTENSION));
        store::save(&model, &path).unwrap();
        assert_eq!(store::load(&path).unwrap().symmetry(), symmetry);
    }
    std::fs::remove_dir_all(out).unwrap();
}

/// The glue of a synth-lmo-dev frame (scene 1, image 12) is fitted where the scene shows it and
/// reported as the canonical one of its equivalents: as close to the truth, through the half
/// turn, as without the symmetry, and scored as well. Before, ICP ran from the canonical pose,
/// a half turn away from where the votes had put the glue, and the glue is symmetric only to
/// 0.02 D: it fitted 6.5° off, and scored 0.36 instead of 0.41.
#[test]
fn a_nearly_symmetric_object_is_fitted_where_it_is_and_reported_canonical() {
    use ppfd_models::detect::detector::{Detector, RunOptions};
    let Some(dir) = shared_test_data("synth-lmo-dev") else {
        return;
    };
    let dataset = BopDataset::open(&dir).unwrap();
    let (scene, image, id) = (1, 12, 11);
    let symmetry = dataset.symmetry(id).unwrap();
    assert_eq!(symmetry.order(), Some(2));
    let mesh = Mesh::from_ply_file(dataset.model_path(id).unwrap()).unwrap();
    let plain = ObjectModel::build(&mesh, id, "glue", &ModelParams::default()).unwrap();
    let symmetric = plain.with_symmetry(&symmetry).unwrap();
    let truth = dataset.ground_truth(scene, image).unwrap()[..]
        .iter()
        .find(|g| g.obj_id == id)
        .unwrap()
        .pose;
    let frame = dataset.depth_frame(scene, image).unwrap();
    let detector = Detector::default();
    let best = |model: &ObjectModel| {
        let found = detector
            .detect(&frame.view(), &[model], &RunOptions::default())
            .unwrap();
        let h = found.objects[0].hypotheses[0];
        // Degrees and mm from the truth or its half turn, whichever is nearer.
        let error = symmetry
            .discrete_with_identity()
            .map(|s| {
                let t = truth * s;
                (
                    h.pose.rotation.angle_to(&t.rotation).to_degrees(),
                    (h.pose.translation.vector - t.translation.vector).norm(),
                )
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap();
        (h, error)
    };
    let (without, e0) = best(&plain);
    let (with, e1) = best(&symmetric);
    eprintln!(
        "without the symmetry: score {:.3}, {:.1}° {:.1} mm; with: score {:.3}, {:.1}° {:.1} mm",
        without.score, e0.0, e0.1, with.score, e1.0, e1.1
    );
    assert!(e1.0 < 2.0 && e1.1 < 3.0, "{e1:?}");
    assert!(
        with.score > without.score - 0.01,
        "{} {}",
        with.score,
        without.score
    );
    let canonical = symmetry.canonical(&with.pose);
    assert!(canonical.rotation.angle_to(&with.pose.rotation) < 1e-4);
}
