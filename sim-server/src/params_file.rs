//! World-parameter files: JSON5 (plain JSON is valid JSON5) holding any subset of
//! [`WorldParams`]' fields; missing fields keep their defaults, unknown fields are errors.
//!
//! A file may also hold a top-level `models` object with per-pedestrian-model overlays, applied on
//! top of the rest of the file when that model drives the pedestrians (for example each model's own
//! calibrated `risk.gamma1`/`risk.gamma2`, which are shared fields of [`WorldParams`]):
//!
//! ```json5
//! {
//!   risk: { gamma1: 0.4, gamma2: 1.2 },             // the world's values (mixed worlds, the AV)
//!   pedestrians: { sfm: { tau: 0.8 } },
//!   models: { ra_sfm: { risk: { gamma1: 0.9 } } },  // used when ra_sfm drives the pedestrians
//! }
//! ```
//!
//! Overlays merge field by field (objects recursively; a `vehicle.shape` replaces whole). Errors
//! name the offending field by its path (`pedestrians.sfm.tau: invalid type ...`).
//!
//! **Shipped defaults.** Without `--params`, every command uses the calibrated parameters
//! (`params/calibrated.json5`, compiled into the binary: [`ParamsDoc::shipped`]); `--params spec`
//! selects model.md's starting values ([`WorldParams::default`]) instead.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::{Map, Value};
use sim_core::params::{
    from_fields, merge, OverlayError, ParamError, PedestrianModel, WorldParams,
};

#[derive(Debug, thiserror::Error)]
pub enum ParamsFileError {
    #[error("reading parameter file {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("parameter file {path}: {message}")]
    Parse { path: String, message: String },
    #[error("parameter file {path}: {source}")]
    Invalid { path: String, source: ParamError },
}

/// The calibrated parameters shipped as defaults (paper Table I calibration, docs/RESULTS.md).
/// Read through `sim-server/shipped/`, a symlink to `params/calibrated.json5`: a file inside the
/// crate, so that the server's sdist (`cargo package`, `maturin sdist`) carries it.
pub const SHIPPED_PARAMS: &str = include_str!("../shipped/calibrated.json5");
const SHIPPED_ORIGIN: &str = "params/calibrated.json5 (shipped defaults)";
/// The `--params` word that selects model.md's starting values instead of the shipped ones.
pub const SPEC_DEFAULTS: &str = "spec";

/// A parsed parameter document: the base fields and the per-model overlays (`models`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParamsDoc {
    /// Where the document came from (for errors), `+`-joined after [`ParamsDoc::overlay`].
    pub origin: String,
    base: Map<String, Value>,
    models: BTreeMap<String, Map<String, Value>>,
}

fn parse_error(origin: &str, message: impl Into<String>) -> ParamsFileError {
    ParamsFileError::Parse {
        path: origin.to_string(),
        message: message.into(),
    }
}

/// The checked parameters of a document's complete field map (sim-core's overlay), an error
/// naming the document and the field.
fn to_world_params(
    fields: Map<String, Value>,
    origin: &str,
) -> Result<WorldParams, ParamsFileError> {
    from_fields(fields).map_err(|e| match e {
        OverlayError::Invalid(source) => ParamsFileError::Invalid {
            path: origin.to_string(),
            source,
        },
        e => parse_error(origin, e.to_string()),
    })
}

impl ParamsDoc {
    /// Parses (but does not yet check against [`WorldParams`]) a JSON5 document.
    pub fn parse(text: &str, origin: &str) -> Result<Self, ParamsFileError> {
        let value: Value = json5::from_str(text).map_err(|e| parse_error(origin, e.to_string()))?;
        let Value::Object(mut base) = value else {
            return Err(parse_error(origin, "expected an object of parameters"));
        };
        let mut models = BTreeMap::new();
        if let Some(section) = base.remove("models") {
            let Value::Object(section) = section else {
                return Err(parse_error(
                    origin,
                    "models: expected an object keyed by pedestrian model",
                ));
            };
            for (name, overlay) in section {
                if PedestrianModel::from_name(&name).is_none() {
                    return Err(parse_error(
                        origin,
                        format!(
                            "models.{name}: unknown pedestrian model (expected {})",
                            PedestrianModel::names()
                        ),
                    ));
                }
                let Value::Object(overlay) = overlay else {
                    return Err(parse_error(
                        origin,
                        format!("models.{name}: expected an object of parameters"),
                    ));
                };
                if overlay.contains_key("models") {
                    return Err(parse_error(
                        origin,
                        format!("models.{name}.models: overlays do not nest"),
                    ));
                }
                models.insert(name, overlay);
            }
        }
        Ok(Self {
            origin: origin.to_string(),
            base,
            models,
        })
    }

    /// Parses and checks a document: the base and every overlay must give valid [`WorldParams`].
    pub fn parse_checked(text: &str, origin: &str) -> Result<Self, ParamsFileError> {
        let doc = Self::parse(text, origin)?;
        doc.check()?;
        Ok(doc)
    }

    /// Checks that the base and every model's parameters deserialize and validate.
    pub fn check(&self) -> Result<(), ParamsFileError> {
        self.world_params(None)?;
        for name in self.models.keys() {
            let model = PedestrianModel::from_name(name).expect("checked on parse");
            self.world_params(Some(model))?;
        }
        Ok(())
    }

    /// The shipped defaults: the calibrated parameter file compiled into the binary.
    pub fn shipped() -> Self {
        Self::parse_checked(SHIPPED_PARAMS, SHIPPED_ORIGIN)
            .expect("the embedded calibrated parameter file is checked by a test")
    }

    /// The document a `--params` argument names: the shipped defaults when absent, model.md's
    /// starting values for the word `spec`, else the file at that path.
    pub fn from_arg(arg: Option<&Path>) -> Result<Self, ParamsFileError> {
        match arg {
            None => Ok(Self::shipped()),
            Some(p) if p.as_os_str() == SPEC_DEFAULTS => Ok(Self {
                origin: "model.md starting values".into(),
                ..Self::default()
            }),
            Some(p) => Self::load(p),
        }
    }

    /// Reads and parses a parameter file.
    pub fn load(path: &Path) -> Result<Self, ParamsFileError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ParamsFileError::Read {
            path: origin.clone(),
            source,
        })?;
        Self::parse_checked(&text, &origin)
    }

    /// Puts `top` over `self`: its base over the base, its overlays over the overlays.
    pub fn overlay(&mut self, top: &ParamsDoc) {
        merge(&mut self.base, &top.base);
        for (name, overlay) in &top.models {
            merge(self.models.entry(name.clone()).or_default(), overlay);
        }
        self.origin = if self.origin.is_empty() {
            top.origin.clone()
        } else {
            format!("{} + {}", self.origin, top.origin)
        };
    }

    /// The parameters for a world whose pedestrians are driven by `model` (`None`: the base,
    /// without any overlay).
    pub fn world_params(
        &self,
        model: Option<PedestrianModel>,
    ) -> Result<WorldParams, ParamsFileError> {
        let mut fields = self.base.clone();
        let origin = match model.and_then(|m| self.models.get(m.name()).map(|o| (m, o))) {
            Some((m, overlay)) => {
                merge(&mut fields, overlay);
                format!("{} (models.{})", self.origin, m.name())
            }
            None => self.origin.clone(),
        };
        to_world_params(fields, &origin)
    }
}

/// World parameters resolved once for each pedestrian model (a document's base with that model's
/// overlay), so that a server applies the right ones at every env creation without re-parsing.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelParams {
    base: WorldParams,
    per_model: Vec<(PedestrianModel, WorldParams)>,
}

impl ModelParams {
    /// Resolves `doc` for every pedestrian model.
    pub fn from_doc(doc: &ParamsDoc) -> Result<Self, ParamsFileError> {
        let per_model = PedestrianModel::ALL
            .into_iter()
            .map(|m| doc.world_params(Some(m)).map(|p| (m, p)))
            .collect::<Result<_, _>>()?;
        Ok(Self {
            base: doc.world_params(None)?,
            per_model,
        })
    }

    /// The base parameters (no model overlay).
    pub fn base(&self) -> &WorldParams {
        &self.base
    }

    /// The parameters of a world whose pedestrians `model` drives.
    pub fn for_model(&self, model: PedestrianModel) -> &WorldParams {
        self.per_model
            .iter()
            .find(|(m, _)| *m == model)
            .map_or(&self.base, |(_, p)| p)
    }
}

impl From<WorldParams> for ModelParams {
    /// The same parameters whatever the model.
    fn from(p: WorldParams) -> Self {
        Self {
            base: p,
            per_model: Vec::new(),
        }
    }
}

/// Parses parameters from JSON5 text; `origin` names the source in errors. A `models` section is
/// checked but not applied (see [`parse_params_for_model`]).
pub fn parse_params(text: &str, origin: &str) -> Result<WorldParams, ParamsFileError> {
    let doc = ParamsDoc::parse_checked(text, origin)?;
    doc.world_params(None)
}

/// Parses parameters from JSON5 text with `model`'s overlay (if the file has one) applied.
pub fn parse_params_for_model(
    text: &str,
    origin: &str,
    model: PedestrianModel,
) -> Result<WorldParams, ParamsFileError> {
    let doc = ParamsDoc::parse_checked(text, origin)?;
    doc.world_params(Some(model))
}

/// Reads and validates a parameter file (the base; a `models` section is checked, not applied).
pub fn load_params(path: &Path) -> Result<WorldParams, ParamsFileError> {
    ParamsDoc::load(path)?.world_params(None)
}

/// Reads a parameter file and applies `model`'s overlay from its `models` section, if any.
pub fn load_params_for_model(
    path: &Path,
    model: PedestrianModel,
) -> Result<WorldParams, ParamsFileError> {
    ParamsDoc::load(path)?.world_params(Some(model))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_defaults_parse_and_differ_from_the_spec_values() {
        let shipped = ParamsDoc::shipped();
        let cr = shipped.world_params(Some(PedestrianModel::CrSfm)).unwrap();
        assert_ne!(
            cr.pedestrians.cr_sfm,
            WorldParams::default().pedestrians.cr_sfm
        );
        let spec = ParamsDoc::from_arg(Some(Path::new("spec"))).unwrap();
        assert_eq!(spec.world_params(None).unwrap(), WorldParams::default());
    }

    #[test]
    fn overlay_applies_per_model() {
        let doc = ParamsDoc::parse_checked(
            "{risk: {gamma1: 0.3}, pedestrians: {sfm: {tau: 0.9}}, models: {ra_sfm: {risk: {gamma1: 1.5}}}}",
            "t",
        )
        .unwrap();
        let base = doc.world_params(None).unwrap();
        assert_eq!(base.risk.gamma1, 0.3);
        assert_eq!(base.pedestrians.sfm.tau, 0.9);
        let ra = doc.world_params(Some(PedestrianModel::RaSfm)).unwrap();
        assert_eq!(ra.risk.gamma1, 1.5);
        assert_eq!(ra.risk.gamma2, base.risk.gamma2);
        assert_eq!(ra.pedestrians.sfm.tau, 0.9);
        let cr = doc.world_params(Some(PedestrianModel::CrSfm)).unwrap();
        assert_eq!(cr, base);
    }

    #[test]
    fn errors_name_the_field() {
        let e = parse_params("{pedestrians: {sfm: {tau: 'fast'}}}", "t").unwrap_err();
        assert!(e.to_string().contains("pedestrians.sfm.tau"), "{e}");
        let e = parse_params("{pedestrians: {sfm: {tua: 1}}}", "t").unwrap_err();
        assert!(e.to_string().contains("tua"), "{e}");
        let e = parse_params("{pedestrians: {sfm: {tau: -1}}}", "t").unwrap_err();
        assert!(e.to_string().contains("pedestrians.sfm.tau"), "{e}");
        let e = parse_params("{models: {ra_sfm: {risk: {gamma2: -1}}}}", "t").unwrap_err();
        assert!(e.to_string().contains("risk.gamma2"), "{e}");
        let e = parse_params("{models: {foo: {}}}", "t").unwrap_err();
        assert!(e.to_string().contains("models.foo"), "{e}");
    }

    #[test]
    fn overlay_of_documents_merges_fields() {
        let mut doc = ParamsDoc::parse("{pedestrians: {sfm: {tau: 0.9, a_ped: 3}}}", "a").unwrap();
        let top = ParamsDoc::parse("{pedestrians: {sfm: {a_ped: 5}}}", "b").unwrap();
        doc.overlay(&top);
        let p = doc.world_params(None).unwrap();
        assert_eq!(p.pedestrians.sfm.tau, 0.9);
        assert_eq!(p.pedestrians.sfm.a_ped, 5.0);
        assert_eq!(doc.origin, "a + b");
    }
}
