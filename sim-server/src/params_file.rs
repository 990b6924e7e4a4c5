//! World-parameter files: JSON5 (plain JSON is valid JSON5) holding any subset of
//! [`WorldParams`]' fields; missing fields keep their defaults, unknown fields are errors.

use std::path::Path;

use sim_core::params::{ParamError, WorldParams};

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

/// Parses parameters from JSON5 text; `origin` names the source in errors.
pub fn parse_params(text: &str, origin: &str) -> Result<WorldParams, ParamsFileError> {
    let params: WorldParams = json5::from_str(text).map_err(|e| ParamsFileError::Parse {
        path: origin.to_string(),
        message: e.to_string(),
    })?;
    params
        .validate()
        .map_err(|source| ParamsFileError::Invalid {
            path: origin.to_string(),
            source,
        })?;
    Ok(params)
}

/// Reads and validates a parameter file.
pub fn load_params(path: &Path) -> Result<WorldParams, ParamsFileError> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ParamsFileError::Read {
        path: origin.clone(),
        source,
    })?;
    parse_params(&text, &origin)
}
