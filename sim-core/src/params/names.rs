//! Parameters set by name: the overlay that a parameter file and a `CreateEnv`'s
//! `pedestrian_params` / `reward_weights` go through, so that both are checked alike (an unknown
//! field, a wrong type, a non-finite value or one [`WorldParams::validate`] refuses is an error
//! naming its path), and the tables of the names a request may use.

use std::collections::BTreeMap;

use serde_json::{Map, Value};

use super::{ParamError, PedestrianModel, SocialForceParams, WorldParams};

/// The names accepted in `CreateEnv.pedestrian_params` (model.md names) besides the social-force
/// ones ([`SocialForceParams::NAMES`], which set that field of every model with social forces),
/// each with the field it sets.
pub const OTHER_PEDESTRIAN_PARAMS: [(&str, &str); 9] = [
    ("gamma1", "risk.gamma1"),
    ("gamma2", "risk.gamma2"),
    ("lambda", "risk.lambda"),
    ("s0", "cognition.s0"),
    ("q", "cognition.q"),
    ("s_o", "cognition.s_o"),
    ("v_ped_max", "ped_speed_max"),
    ("ped_radius", "ped_radius"),
    ("ped_goal_radius", "ped_goal_radius"),
];

/// The names accepted in `CreateEnv.reward_weights` (the protocol's `REWARD_WEIGHT_DEFAULTS`),
/// each with the field it sets.
pub const REWARD_WEIGHTS: [(&str, &str); 7] = [
    ("progress", "reward.progress"),
    ("success", "reward.success"),
    ("collision", "reward.collision"),
    ("danger", "reward.danger"),
    ("danger_clearance", "reward.danger_clearance"),
    ("comfort_jerk", "reward.jerk_penalty"),
    ("comfort_omega", "reward.yaw_rate_penalty"),
];

/// A refused overlay, named by the field's path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OverlayError {
    /// An unknown field, or a value of the wrong type (`pedestrians.sfm.tau: invalid type ...`).
    #[error("{0}")]
    Field(String),
    /// A value the parameters' own check refuses.
    #[error(transparent)]
    Invalid(#[from] ParamError),
    /// A name no table holds.
    #[error("unknown {what} {name:?}; known: {known}")]
    UnknownName {
        what: &'static str,
        name: String,
        known: String,
    },
}

/// The fields a `pedestrian_params` name sets, or None for an unknown name.
pub fn pedestrian_param_fields(name: &str) -> Option<Vec<String>> {
    if SocialForceParams::NAMES.contains(&name) {
        let defaults = WorldParams::default().pedestrians;
        let sets = PedestrianModel::ALL
            .into_iter()
            .filter(|&m| defaults.for_model(m).is_some());
        return Some(
            sets.map(|m| format!("pedestrians.{}.{name}", m.name()))
                .collect(),
        );
    }
    let (_, field) = OTHER_PEDESTRIAN_PARAMS.iter().find(|(n, _)| *n == name)?;
    Some(vec![field.to_string()])
}

/// Recursively merges `top` into `bottom`; a `shape` (a tagged enum) is replaced whole.
pub fn merge(bottom: &mut Map<String, Value>, top: &Map<String, Value>) {
    for (key, value) in top {
        match (bottom.get_mut(key), value) {
            (Some(Value::Object(b)), Value::Object(t)) if key != "shape" => merge(b, t),
            _ => {
                bottom.insert(key.clone(), value.clone());
            }
        }
    }
}

/// The parameters of a complete field map, checked (see the module documentation).
pub fn from_fields(fields: Map<String, Value>) -> Result<WorldParams, OverlayError> {
    let params: WorldParams =
        serde_path_to_error::deserialize(Value::Object(fields)).map_err(|e| {
            let path = e.path().to_string();
            let inner = e.into_inner();
            if path == "." {
                OverlayError::Field(inner.to_string())
            } else {
                OverlayError::Field(format!("{path}: {inner}"))
            }
        })?;
    params.validate()?;
    Ok(params)
}

impl WorldParams {
    /// These parameters with `values` set at their dotted paths (`pedestrians.sfm.tau`), checked
    /// as a parameter file's fields are.
    pub fn with_values(&self, values: &[(String, f64)]) -> Result<WorldParams, OverlayError> {
        let Ok(Value::Object(mut fields)) = serde_json::to_value(self) else {
            unreachable!("WorldParams serializes to a JSON object");
        };
        let mut top = Map::new();
        for (path, value) in values {
            let mut at = &mut top;
            let mut keys = path.split('.').peekable();
            while let Some(key) = keys.next() {
                if keys.peek().is_none() {
                    // A non-finite f64 becomes null, which the f64 field then refuses by its path.
                    at.insert(key.to_string(), Value::from(*value));
                } else {
                    let next = at
                        .entry(key.to_string())
                        .or_insert_with(|| Value::Object(Map::new()));
                    let Value::Object(next) = next else {
                        unreachable!("a path's inner keys are objects");
                    };
                    at = next;
                }
            }
        }
        merge(&mut fields, &top);
        from_fields(fields)
    }

    /// These parameters with a request's `pedestrian_params` and `reward_weights` set by name
    /// ([`pedestrian_param_fields`], [`REWARD_WEIGHTS`]).
    pub fn with_named(
        &self,
        pedestrian_params: &BTreeMap<String, f64>,
        reward_weights: &BTreeMap<String, f64>,
    ) -> Result<WorldParams, OverlayError> {
        let mut values = Vec::new();
        for (name, &v) in pedestrian_params {
            let fields = pedestrian_param_fields(name).ok_or_else(|| {
                let known: Vec<&str> = SocialForceParams::NAMES
                    .iter()
                    .copied()
                    .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n))
                    .collect();
                OverlayError::UnknownName {
                    what: "pedestrian parameter",
                    name: name.clone(),
                    known: known.join(", "),
                }
            })?;
            values.extend(fields.into_iter().map(|f| (f, v)));
        }
        for (name, &v) in reward_weights {
            let (_, field) = REWARD_WEIGHTS
                .iter()
                .find(|(n, _)| n == name)
                .ok_or_else(|| OverlayError::UnknownName {
                    what: "reward weight",
                    name: name.clone(),
                    known: REWARD_WEIGHTS.map(|(n, _)| n).join(", "),
                })?;
            values.push((field.to_string(), v));
        }
        if values.is_empty() {
            return Ok(*self);
        }
        self.with_values(&values)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_override_name_sets_its_field_and_nothing_else() {
        let base = WorldParams::default();
        let none = BTreeMap::new();
        let pedestrian = SocialForceParams::NAMES
            .iter()
            .copied()
            .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n))
            .map(|n| (n, true));
        let reward = REWARD_WEIGHTS.iter().map(|(n, _)| (*n, false));
        for (name, is_pedestrian) in pedestrian.chain(reward) {
            let one = BTreeMap::from([(name.to_string(), 0.123)]);
            let (p, r) = if is_pedestrian {
                (&one, &none)
            } else {
                (&none, &one)
            };
            let set = base
                .with_named(p, r)
                .unwrap_or_else(|e| panic!("{name}: {e:?}"));
            // Every field that changed is one the name stands for, and now holds 0.123.
            let (before, after) = (
                serde_json::to_value(base).unwrap(),
                serde_json::to_value(set).unwrap(),
            );
            let mut changed = changed_leaves(&before, &after, "");
            let mut expected: Vec<String> = if is_pedestrian {
                pedestrian_param_fields(name).unwrap()
            } else {
                let field = REWARD_WEIGHTS.iter().find(|(n, _)| *n == name).unwrap().1;
                vec![field.to_string()]
            };
            changed.sort();
            expected.sort();
            assert_eq!(changed, expected, "{name}");
            for field in &expected {
                let leaf = field.split('.').fold(&after, |v, k| &v[k]);
                assert_eq!(leaf.as_f64(), Some(0.123), "{field}");
            }
        }
        let social = pedestrian_param_fields("tau").unwrap();
        assert_eq!(social.len(), 3, "sfm, ra_sfm and cr_sfm: {social:?}");
        let e = base
            .with_named(&[("nope".to_string(), 1.0)].into(), &none)
            .unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains("ped_goal_radius") && e.contains("lambda3"),
            "{e}"
        );
        let e = base
            .with_named(&none, &[("nope".to_string(), 1.0)].into())
            .unwrap_err();
        assert!(e.to_string().contains("unknown reward weight"), "{e}");
        let e = base
            .with_named(&[("tau".to_string(), -1.0)].into(), &none)
            .unwrap_err();
        assert!(e.to_string().contains("tau"), "{e}");
    }

    /// The dotted paths of the leaves that differ between two JSON values.
    fn changed_leaves(a: &serde_json::Value, b: &serde_json::Value, path: &str) -> Vec<String> {
        match (a, b) {
            (serde_json::Value::Object(x), serde_json::Value::Object(y)) => x
                .iter()
                .flat_map(|(k, v)| {
                    let at = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    changed_leaves(v, &y[k], &at)
                })
                .collect(),
            _ if a != b => vec![path.to_string()],
            _ => vec![],
        }
    }
}
