//! The versioned scenario file format and its validating loader.
//!
//! A scenario file is a [`ScenarioPool`] serialised as JSON (see `scenarios/FORMAT.md` for every
//! field and unit). [`save_pool`] writes compact JSON deterministically (struct fields in
//! declaration order, floats in shortest round-trip form, so a load/save round trip is exact).
//! [`load_pool`] parses and then validates; every [`PoolError`] names the file (`origin`), the
//! scenario (index and, when known, name), the agent (index and, when known, `record_id`) and the
//! field (a JSON path inside the scenario or agent, such as `positions[4][0]`).
//!
//! Validation rules, checked in this order:
//! 1. `version` equals [`SCENARIO_FORMAT_VERSION`].
//! 2. per scenario: non-empty `name`, unique across the pool; `dt` equal to [`DT`] (0.5 s,
//!    tolerance 1e-9); at least one agent; `ego` indexes an agent that is a vehicle.
//! 3. per agent: `record_id` unique in the scenario; `positions` non-empty; `velocities` as long
//!    as `positions`; `start_step + len - 1` fits in a `u32`; every number finite, positions
//!    within [`MAX_ABS_POSITION`] metres and velocities within [`MAX_ABS_VELOCITY`] m/s (JSON
//!    cannot hold NaN or infinity; `null` or an out-of-range literal such as `1e400` is reported
//!    as a decode error at its path, and finiteness is checked anyway for pools built in memory).
//! 4. overlap: under the footprints of [`crate::footprint`], with [`OverlapCheck::Spawn`] (what
//!    [`load_pool`] uses) every pair of agents must have clearance `> 0` at the first step at
//!    which both are present, so that no world starts or spawns an agent in collision; recorded
//!    tracks may come closer later (the general HBS pool does, the recorded pedestrians walk in
//!    groups). [`OverlapCheck::AllSteps`] checks every step; the paper-like pool passes it.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use sim_core::scenario::{AgentKind, ScenarioPool, SCENARIO_FORMAT_VERSION};

use crate::footprint::{first_overlap_any_step, first_spawn_overlap, Overlap};

/// The simulation step every scenario must be sampled at (seconds).
pub const DT: f64 = 0.5;
/// Plausibility limit on the absolute value of a position coordinate (metres).
pub const MAX_ABS_POSITION: f64 = 1.0e6;
/// Plausibility limit on the absolute value of a velocity component (m/s).
pub const MAX_ABS_VELOCITY: f64 = 1.0e3;

/// Which overlap rule [`validate_pool`] applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverlapCheck {
    /// Each pair at the first step at which both agents are present.
    Spawn,
    /// Each pair at every step at which both agents are present.
    AllSteps,
}

/// The scenario an error is about.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScenarioRef {
    /// Index in the pool's `scenarios`.
    pub index: usize,
    /// The scenario's `name`, when it could be read.
    pub name: Option<String>,
}

/// The agent an error is about.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AgentRef {
    /// Index in the scenario's `agents`.
    pub index: usize,
    /// The agent's `record_id`, when it could be read.
    pub record_id: Option<u64>,
}

/// What is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Problem {
    #[error("cannot read the file: {0}")]
    Io(String),
    #[error("malformed JSON: {0}")]
    Syntax(String),
    #[error("cannot decode: {0}")]
    Decode(String),
    #[error("unsupported format version {found} (this build reads version {expected})")]
    Version { found: u32, expected: u32 },
    #[error("value {0} is not a finite number")]
    NotFinite(f64),
    #[error("|{value:e}| exceeds the plausibility limit {limit:e}")]
    TooLarge { value: f64, limit: f64 },
    #[error("{0} is negative (a speed)")]
    Negative(f64),
    #[error("empty track (at least one sample is required)")]
    EmptyTrack,
    #[error("{velocities} velocities for {positions} positions (lengths must match)")]
    LengthMismatch { positions: usize, velocities: usize },
    #[error("start_step + track length overflows u32")]
    StepOverflow,
    #[error("dt is {0} s, must be 0.5 s")]
    WrongDt(f64),
    #[error("scenario has no agents")]
    NoAgents,
    #[error("ego index {ego} out of range ({agents} agents)")]
    EgoOutOfRange { ego: usize, agents: usize },
    #[error("ego agent #{ego} is a pedestrian, must be a vehicle")]
    EgoNotVehicle { ego: usize },
    #[error("empty name")]
    EmptyName,
    #[error("duplicate scenario name (first used by scenario #{first_index})")]
    DuplicateName { first_index: usize },
    #[error("duplicate record_id {record_id} (first used by agent #{first_index})")]
    DuplicateRecordId { record_id: u64, first_index: usize },
    #[error(
        "overlaps agent #{other_index} (record_id {other_record_id}) at step {step} \
         (clearance {clearance} m <= 0)"
    )]
    Overlap {
        other_index: usize,
        other_record_id: u64,
        step: u32,
        clearance: f64,
    },
}

/// A scenario file that cannot be used, with where the problem is.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{origin}: {loc}{problem}", loc = Location(.scenario, .agent, .field))]
pub struct PoolError {
    /// The file (or other origin) the pool came from.
    pub origin: String,
    pub scenario: Option<ScenarioRef>,
    pub agent: Option<AgentRef>,
    /// Path of the offending field inside the agent, the scenario or the pool (empty when the
    /// document itself is malformed and no field is known).
    pub field: String,
    /// What is wrong (boxed to keep `Result<_, PoolError>` small).
    pub problem: Box<Problem>,
}

struct Location<'a>(&'a Option<ScenarioRef>, &'a Option<AgentRef>, &'a String);

impl fmt::Display for Location<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(s) = self.0 {
            write!(f, "scenario #{}", s.index)?;
            if let Some(n) = &s.name {
                write!(f, " `{n}`")?;
            }
            if let Some(a) = self.1 {
                write!(f, ", agent #{}", a.index)?;
                if let Some(r) = a.record_id {
                    write!(f, " (record_id {r})")?;
                }
            }
            write!(f, ": ")?;
        }
        if !self.2.is_empty() {
            write!(f, "field `{}`: ", self.2)?;
        }
        Ok(())
    }
}

/// Serialise a pool as compact JSON followed by a newline; deterministic.
pub fn save_pool(pool: &ScenarioPool) -> String {
    // Serialising plain structs of numbers, strings and enums cannot fail.
    let mut s = serde_json::to_string(pool).unwrap_or_default();
    s.push('\n');
    s
}

/// Read, parse and validate a pool file; `origin` in errors is the path as given.
pub fn load_pool_file(path: &Path) -> Result<ScenarioPool, PoolError> {
    let origin = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| PoolError {
        origin: origin.clone(),
        scenario: None,
        agent: None,
        field: String::new(),
        problem: Box::new(Problem::Io(e.to_string())),
    })?;
    load_pool(&bytes, &origin)
}

/// Parse and validate a pool (spawn overlap rule); `origin` names the file in errors.
pub fn load_pool(bytes: &[u8], origin: &str) -> Result<ScenarioPool, PoolError> {
    let text = std::str::from_utf8(bytes).map_err(|e| PoolError {
        origin: origin.to_string(),
        scenario: None,
        agent: None,
        field: String::new(),
        problem: Box::new(Problem::Syntax(format!("not UTF-8: {e}"))),
    })?;
    let mut de = serde_json::Deserializer::from_str(text);
    let pool: ScenarioPool = match serde_path_to_error::deserialize(&mut de) {
        Ok(p) => p,
        Err(e) => return Err(decode_error(text, origin, e)),
    };
    if let Err(e) = de.end() {
        return Err(PoolError {
            origin: origin.to_string(),
            scenario: None,
            agent: None,
            field: String::new(),
            problem: Box::new(Problem::Syntax(e.to_string())),
        });
    }
    validate_pool(&pool, origin, OverlapCheck::Spawn)?;
    Ok(pool)
}

fn decode_error(
    text: &str,
    origin: &str,
    e: serde_path_to_error::Error<serde_json::Error>,
) -> PoolError {
    use serde_path_to_error::Segment;
    let segments: Vec<&Segment> = e.path().iter().collect();
    let inner = e.inner();
    let message = inner.to_string();
    // `key[index]` at the front of the path: the index, and the path moved past it.
    let take_indexed = |rest: &mut &[&Segment], name: &str| match *rest {
        [Segment::Map { key }, Segment::Seq { index }, tail @ ..] if key == name => {
            *rest = tail;
            Some(*index)
        }
        _ => None,
    };
    let mut rest = &segments[..];
    let mut scenario =
        take_indexed(&mut rest, "scenarios").map(|index| ScenarioRef { index, name: None });
    let mut agent = match scenario {
        Some(_) => take_indexed(&mut rest, "agents").map(|index| AgentRef {
            index,
            record_id: None,
        }),
        None => None,
    };
    let mut field = String::new();
    for seg in rest {
        match seg {
            Segment::Seq { index } => field.push_str(&format!("[{index}]")),
            Segment::Map { key } | Segment::Enum { variant: key } => {
                if !field.is_empty() {
                    field.push('.');
                }
                field.push_str(key);
            }
            Segment::Unknown => field.push_str(".?"),
        }
    }
    // "missing field `x`" points at the struct that lacks `x`: name the field itself.
    if let Some(missing) = message
        .strip_prefix("missing field `")
        .and_then(|m| m.split('`').next())
    {
        if !field.is_empty() {
            field.push('.');
        }
        field.push_str(missing);
    }
    // Recover the scenario name and record_id when the document is well-formed JSON.
    if let Ok(value) = serde_json::from_str::<serde_json::Value>(text) {
        if let Some(s) = scenario.as_mut() {
            let sv = &value["scenarios"][s.index];
            s.name = sv["name"].as_str().map(str::to_string);
            if let Some(a) = agent.as_mut() {
                a.record_id = sv["agents"][a.index]["record_id"].as_u64();
            }
        }
    }
    let problem = if inner.is_syntax() || inner.is_eof() {
        Problem::Syntax(message)
    } else {
        Problem::Decode(message)
    };
    PoolError {
        origin: origin.to_string(),
        scenario,
        agent,
        field,
        problem: Box::new(problem),
    }
}

/// Validate a pool already in memory with the given overlap rule (see the module docs).
pub fn validate_pool(
    pool: &ScenarioPool,
    origin: &str,
    overlap: OverlapCheck,
) -> Result<(), PoolError> {
    let err = |scenario: Option<ScenarioRef>, agent: Option<AgentRef>, field: &str, problem| {
        let problem: Problem = problem;
        Err(PoolError {
            origin: origin.to_string(),
            scenario,
            agent,
            field: field.to_string(),
            problem: Box::new(problem),
        })
    };
    if pool.version != SCENARIO_FORMAT_VERSION {
        return err(
            None,
            None,
            "version",
            Problem::Version {
                found: pool.version,
                expected: SCENARIO_FORMAT_VERSION,
            },
        );
    }
    let mut names: HashMap<&str, usize> = HashMap::new();
    for (si, sc) in pool.scenarios.iter().enumerate() {
        let sref = || {
            Some(ScenarioRef {
                index: si,
                name: Some(sc.name.clone()),
            })
        };
        if sc.name.is_empty() {
            return err(sref(), None, "name", Problem::EmptyName);
        }
        if let Some(&first_index) = names.get(sc.name.as_str()) {
            return err(sref(), None, "name", Problem::DuplicateName { first_index });
        }
        names.insert(&sc.name, si);
        if !sc.dt.is_finite() || (sc.dt - DT).abs() > 1e-9 {
            return err(sref(), None, "dt", Problem::WrongDt(sc.dt));
        }
        if sc.agents.is_empty() {
            return err(sref(), None, "agents", Problem::NoAgents);
        }
        match sc.agents.get(sc.ego) {
            None => {
                return err(
                    sref(),
                    None,
                    "ego",
                    Problem::EgoOutOfRange {
                        ego: sc.ego,
                        agents: sc.agents.len(),
                    },
                )
            }
            Some(a) if a.kind != AgentKind::Vehicle => {
                return err(sref(), None, "ego", Problem::EgoNotVehicle { ego: sc.ego })
            }
            Some(_) => {}
        }
        let mut ids: HashMap<u64, usize> = HashMap::new();
        for (ai, ag) in sc.agents.iter().enumerate() {
            let aref = || {
                Some(AgentRef {
                    index: ai,
                    record_id: Some(ag.record_id),
                })
            };
            if let Some(&first_index) = ids.get(&ag.record_id) {
                return err(
                    sref(),
                    aref(),
                    "record_id",
                    Problem::DuplicateRecordId {
                        record_id: ag.record_id,
                        first_index,
                    },
                );
            }
            ids.insert(ag.record_id, ai);
            if ag.positions.is_empty() {
                return err(sref(), aref(), "positions", Problem::EmptyTrack);
            }
            if ag.velocities.len() != ag.positions.len() {
                return err(
                    sref(),
                    aref(),
                    "velocities",
                    Problem::LengthMismatch {
                        positions: ag.positions.len(),
                        velocities: ag.velocities.len(),
                    },
                );
            }
            if u32::try_from(ag.positions.len() - 1)
                .ok()
                .and_then(|n| ag.start_step.checked_add(n))
                .is_none()
            {
                return err(sref(), aref(), "start_step", Problem::StepOverflow);
            }
            for (field, track, limit) in [
                ("positions", &ag.positions, MAX_ABS_POSITION),
                ("velocities", &ag.velocities, MAX_ABS_VELOCITY),
            ] {
                for (k, sample) in track.iter().enumerate() {
                    for (c, &value) in sample.iter().enumerate() {
                        let problem = if !value.is_finite() {
                            Problem::NotFinite(value)
                        } else if value.abs() > limit {
                            Problem::TooLarge { value, limit }
                        } else {
                            continue;
                        };
                        return err(sref(), aref(), &format!("{field}[{k}][{c}]"), problem);
                    }
                }
            }
            if let Some(v) = ag.desired_speed {
                let problem = if !v.is_finite() {
                    Some(Problem::NotFinite(v))
                } else if v < 0.0 {
                    Some(Problem::Negative(v))
                } else if v > MAX_ABS_VELOCITY {
                    Some(Problem::TooLarge {
                        value: v,
                        limit: MAX_ABS_VELOCITY,
                    })
                } else {
                    None
                };
                if let Some(problem) = problem {
                    return err(sref(), aref(), "desired_speed", problem);
                }
            }
        }
        let found = match overlap {
            OverlapCheck::Spawn => first_spawn_overlap(&sc.agents),
            OverlapCheck::AllSteps => first_overlap_any_step(&sc.agents),
        };
        if let Some(Overlap {
            a,
            b,
            step,
            clearance,
        }) = found
        {
            // Name the agent that appears later (the higher index on a tie); the other is named
            // in the problem.
            let (me, other) = if sc.agents[a].start_step > sc.agents[b].start_step {
                (a, b)
            } else {
                (b, a)
            };
            let ag = &sc.agents[me];
            return err(
                sref(),
                Some(AgentRef {
                    index: me,
                    record_id: Some(ag.record_id),
                }),
                &format!("positions[{}]", step - ag.start_step),
                Problem::Overlap {
                    other_index: other,
                    other_record_id: sc.agents[other].record_id,
                    step,
                    clearance,
                },
            );
        }
    }
    Ok(())
}
