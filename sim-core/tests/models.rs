//! The one list of pedestrian models (`params::MODELS`): everything that lists models agrees
//! with it. The wire protocol reuses the enum itself; the Python side reads
//! `clients/src/sharedspace/models.json`, which must equal `models_json()` (regenerate it with
//! `UPDATE_GOLDEN=1 cargo test -p sim-core --test models`).

use std::path::PathBuf;

use sim_core::model::pedestrian::ModelForces;
use sim_core::params::{models_json, PedestrianModel, PedestrianParams, MODELS};

#[test]
fn the_table_is_in_enum_order_and_names_are_unique() {
    for (k, info) in MODELS.iter().enumerate() {
        assert_eq!(info.model.index(), k, "{}", info.name);
        assert_eq!(PedestrianModel::ALL[k], info.model);
        assert_eq!(PedestrianModel::from_name(info.name), Some(info.model));
        assert!(info.weighting.is_none_or(|w| w.risk || !w.cognitive));
    }
    let mut names: Vec<_> = MODELS.iter().map(|m| m.name).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), MODELS.len());
}

#[test]
fn a_model_has_parameters_exactly_when_it_has_social_forces() {
    let params = PedestrianParams::default();
    for m in PedestrianModel::ALL {
        let p = params.for_model(m);
        assert_eq!(p.is_some(), m.info().weighting.is_some(), "{}", m.name());
        assert_eq!(
            p.and_then(|p| ModelForces::new(m, p)).is_some(),
            p.is_some(),
            "{}",
            m.name()
        );
    }
}

#[test]
fn the_python_list_of_models_is_the_table() {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../clients/src/sharedspace/models.json");
    let want = models_json();
    if std::env::var("UPDATE_GOLDEN").is_ok_and(|v| !v.is_empty() && v != "0") {
        std::fs::write(&path, &want).expect("write models.json");
    }
    let got = std::fs::read_to_string(&path).unwrap_or_default();
    assert_eq!(
        got,
        want,
        "{} is out of step with sim_core::params::MODELS; regenerate it with \
         `UPDATE_GOLDEN=1 cargo test -p sim-core --test models`",
        path.display()
    );
}
