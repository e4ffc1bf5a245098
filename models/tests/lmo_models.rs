//! Model building on the real LM-O models (`../shared/data/lmo`): every model builds, its
//! diameter agrees with BOP's `models_info.json`, and it survives the store.

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
