//! `sim-server eval-peds`: the paper's Table I (model.md section 9) on a scenario pool. Every
//! scenario of one split is run with the vehicles replaying their record and the pedestrians driven
//! by each requested model; ADE, FDE and the collision rate are reported per model and per
//! scenario (JSON, see docs/RESULTS.md).
//!
//! Parameters: `--params FILE` (JSON5, [`crate::params_file`], with optional per-model `models`
//! overlays), then `--params-json TEXT` (`-`: read it from standard input) on top. With `--batch`,
//! standard input holds one parameter document per line (JSON or JSON5, each over `--params`), and
//! one JSON result line is printed and flushed per input line, so that an optimiser can drive one
//! process; a line whose parameters are refused gives `{"index": k, "error": "..."}` and the batch
//! goes on.
//!
//! Scenarios are evaluated on all cores (`--threads`); results do not depend on the thread count.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use serde_json::{json, Value};
use sim_core::metrics::PedestrianEvalSummary;
use sim_core::params::{PedestrianModel, WorldParams};
use sim_core::pedeval::evaluate_scenario;
use sim_core::scenario::{Scenario, ScenarioPool, Split};
use sim_core::world::AgentId;

use crate::params_file::ParamsDoc;
use crate::rollout::agent_json;

/// Command-line arguments of `eval-peds`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct EvalPedsArgs {
    /// Scenario pool file (JSON, scenarios/FORMAT.md) or an embedded pool,
    /// `embedded:hbs-paper` or `embedded:hbs-general`; `hbs-paper` when absent.
    #[arg(long)]
    pub pool: Option<PathBuf>,
    /// World-parameter file (JSON5; may hold per-model overlays under `models`).
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Parameter overrides as a JSON/JSON5 document over `--params`; `-` reads standard input.
    #[arg(long)]
    pub params_json: Option<String>,
    /// Split to evaluate: train, test or all.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Comma-separated pedestrian models (default: every model but `replay`).
    #[arg(long, default_value_t = evaluated_models())]
    pub models: String,
    /// Only these scenarios (comma-separated names) of the split.
    #[arg(long)]
    pub scenarios: Option<String>,
    /// Only the first N scenarios of the split (after `--scenarios`).
    #[arg(long)]
    pub limit: Option<usize>,
    /// Summary JSON (per model and per scenario); standard output when absent.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Folder for one JSON file per scenario with the recorded and every model's simulated tracks.
    #[arg(long)]
    pub trajectories: Option<PathBuf>,
    /// Read one parameter document per line from standard input, print one result line each.
    #[arg(long)]
    pub batch: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// One scenario's result under one model.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioResult {
    pub name: String,
    pub ade: f64,
    pub fde: f64,
    pub collided: bool,
    /// Simulated pedestrians.
    pub pedestrians: usize,
    /// Simulated pedestrians that reached their goal (and left) before their record ended.
    pub early_arrivals: usize,
    /// Simulated tracks (kept only when asked for).
    pub simulated: Option<Vec<(AgentId, Vec<[f64; 2]>)>>,
}

/// One model's results on the selected scenarios.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelResult {
    pub model: PedestrianModel,
    pub summary: PedestrianEvalSummary,
    pub scenarios: Vec<ScenarioResult>,
}

impl ModelResult {
    /// The calibration objective: ADE + FDE.
    pub fn objective(&self) -> f64 {
        self.summary.ade + self.summary.fde
    }

    /// Share of simulated pedestrians that arrived before their record ended.
    pub fn early_arrival_share(&self) -> f64 {
        let peds: usize = self.scenarios.iter().map(|s| s.pedestrians).sum();
        let early: usize = self.scenarios.iter().map(|s| s.early_arrivals).sum();
        if peds == 0 {
            0.0
        } else {
            early as f64 / peds as f64
        }
    }

    /// Summary JSON; with `per_scenario` the per-scenario values too.
    pub fn to_json(&self, per_scenario: bool) -> Value {
        let mut v = json!({
            "episodes": self.summary.episodes,
            "ade": self.summary.ade,
            "fde": self.summary.fde,
            "collision_rate": self.summary.collision_rate,
            "objective": self.objective(),
            "early_arrival_share": self.early_arrival_share(),
        });
        if per_scenario {
            v["scenarios"] = self
                .scenarios
                .iter()
                .map(|s| {
                    json!({
                        "name": s.name,
                        "ade": s.ade,
                        "fde": s.fde,
                        "collided": s.collided,
                        "pedestrians": s.pedestrians,
                        "early_arrivals": s.early_arrivals,
                    })
                })
                .collect();
        }
        v
    }
}

/// Every model an evaluation can run, comma-separated: all but `replay`, which only repeats the
/// recording.
fn evaluated_models() -> String {
    let names: Vec<&str> = PedestrianModel::ALL
        .iter()
        .filter(|m| **m != PedestrianModel::Replay)
        .map(|m| m.name())
        .collect();
    names.join(",")
}

/// Parses `cv,sfm,...` into models (no duplicates).
pub fn parse_models(text: &str) -> Result<Vec<PedestrianModel>, String> {
    let mut models = Vec::new();
    for name in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let m = PedestrianModel::from_name(name)
            .filter(|m| *m != PedestrianModel::Replay)
            .ok_or_else(|| {
                format!(
                    "--models: unknown pedestrian model `{name}` (expected one of {})",
                    evaluated_models()
                )
            })?;
        if !models.contains(&m) {
            models.push(m);
        }
    }
    if models.is_empty() {
        return Err("--models: no model given".into());
    }
    Ok(models)
}

/// Selects the scenarios of `split` (`train`, `test` or `all`), optionally by name and count.
pub fn select_scenarios(
    pool: &ScenarioPool,
    split: &str,
    names: Option<&str>,
    limit: Option<usize>,
) -> Result<Vec<Arc<Scenario>>, String> {
    let split = match split {
        "train" => Some(Split::Train),
        "test" => Some(Split::Test),
        "all" => None,
        other => return Err(format!("--split `{other}`: expected train, test or all")),
    };
    let in_split = |s: &&Scenario| match split {
        Some(sp) => s.split == sp,
        None => true,
    };
    let mut chosen: Vec<&Scenario> = match names {
        None => pool.scenarios.iter().filter(in_split).collect(),
        Some(names) => names
            .split(',')
            .map(str::trim)
            .filter(|n| !n.is_empty())
            .map(|n| {
                pool.scenarios
                    .iter()
                    .filter(in_split)
                    .find(|s| s.name == n)
                    .ok_or_else(|| format!("--scenarios: no scenario `{n}` in the split"))
            })
            .collect::<Result<_, _>>()?,
    };
    if let Some(k) = limit {
        chosen.truncate(k);
    }
    if chosen.is_empty() {
        return Err("no scenario selected".into());
    }
    Ok(chosen.into_iter().map(|s| Arc::new(s.clone())).collect())
}

/// Evaluates every `(model, scenario)` pair on `threads` threads; `params[k]` is `models[k]`'s.
pub fn evaluate_models(
    scenarios: &[Arc<Scenario>],
    models: &[PedestrianModel],
    params: &[WorldParams],
    keep_tracks: bool,
    threads: usize,
) -> Result<Vec<ModelResult>, String> {
    assert_eq!(models.len(), params.len());
    let jobs = models.len() * scenarios.len();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<ScenarioResult, String>>>> = Mutex::new(vec![None; jobs]);
    let worker = || loop {
        let k = next.fetch_add(1, Ordering::Relaxed);
        if k >= jobs {
            break;
        }
        let (m, s) = (k / scenarios.len(), k % scenarios.len());
        let r = evaluate_one(&scenarios[s], &params[m], models[m], keep_tracks);
        results.lock().expect("no panics while locked")[k] = Some(r);
    };
    let threads = threads.clamp(1, jobs.max(1));
    std::thread::scope(|scope| {
        for _ in 1..threads {
            scope.spawn(worker);
        }
        worker();
    });
    let mut results = results
        .into_inner()
        .expect("no panics while locked")
        .into_iter();
    let mut out = Vec::with_capacity(models.len());
    for &model in models {
        let scen: Vec<ScenarioResult> = results
            .by_ref()
            .take(scenarios.len())
            .map(|r| r.expect("every job ran"))
            .collect::<Result<_, _>>()?;
        let episodes: Vec<_> = scen
            .iter()
            .map(|s| {
                (
                    sim_core::metrics::DisplacementErrors {
                        ade: s.ade,
                        fde: s.fde,
                    },
                    s.collided,
                )
            })
            .collect();
        out.push(ModelResult {
            model,
            summary: PedestrianEvalSummary::of(&episodes),
            scenarios: scen,
        });
    }
    Ok(out)
}

fn evaluate_one(
    scenario: &Arc<Scenario>,
    params: &WorldParams,
    model: PedestrianModel,
    keep_tracks: bool,
) -> Result<ScenarioResult, String> {
    let ep = evaluate_scenario(scenario.clone(), params, model)
        .map_err(|e| format!("scenario `{}`, model {}: {e}", scenario.name, model.name()))?;
    let early_arrivals = ep
        .simulated
        .iter()
        .filter(|(id, track)| track.len() < scenario.agents[*id as usize].positions.len())
        .count();
    Ok(ScenarioResult {
        name: scenario.name.clone(),
        ade: ep.errors.ade,
        fde: ep.errors.fde,
        collided: ep.collided,
        pedestrians: ep.simulated.len(),
        early_arrivals,
        simulated: keep_tracks.then(|| {
            ep.simulated
                .iter()
                .map(|(id, t)| (*id, t.iter().map(|p| [p.x, p.y]).collect()))
                .collect()
        }),
    })
}

/// Each model's parameters from a document (its overlay applied).
pub fn params_for_models(
    doc: &ParamsDoc,
    models: &[PedestrianModel],
) -> Result<Vec<WorldParams>, String> {
    models
        .iter()
        .map(|&m| doc.world_params(Some(m)).map_err(|e| e.to_string()))
        .collect()
}

fn load_pool(path: Option<&Path>) -> Result<ScenarioPool, String> {
    match path {
        Some(p) => scenarios::embedded::pool_from_arg(p),
        None => Ok(scenarios::embedded::default_pool()),
    }
}

/// The base parameter document: `--params` with `--params-json` over it.
fn base_doc(args: &EvalPedsArgs) -> Result<ParamsDoc, String> {
    let mut doc = ParamsDoc::from_arg(args.params.as_deref()).map_err(|e| e.to_string())?;
    if let Some(text) = &args.params_json {
        let (text, origin) = if text == "-" {
            let mut s = String::new();
            std::io::Read::read_to_string(&mut std::io::stdin(), &mut s)
                .map_err(|e| format!("reading --params-json from standard input: {e}"))?;
            (s, "--params-json (stdin)")
        } else {
            (text.clone(), "--params-json")
        };
        let top = ParamsDoc::parse(&text, origin).map_err(|e| e.to_string())?;
        doc.overlay(&top);
    }
    if doc.origin.is_empty() {
        doc.origin = "defaults".into();
    }
    doc.check().map_err(|e| e.to_string())?;
    Ok(doc)
}

fn threads(args: &EvalPedsArgs) -> usize {
    args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    })
}

/// Runs a non-batch evaluation and returns the summary document (and writes the trajectory files
/// when asked).
pub fn run_summary(args: &EvalPedsArgs) -> Result<Value, String> {
    let pool = load_pool(args.pool.as_deref())?;
    let scen = select_scenarios(&pool, &args.split, args.scenarios.as_deref(), args.limit)?;
    let models = parse_models(&args.models)?;
    let doc = base_doc(args)?;
    let params = params_for_models(&doc, &models)?;
    let keep = args.trajectories.is_some();
    let results = evaluate_models(&scen, &models, &params, keep, threads(args))?;
    if let Some(dir) = &args.trajectories {
        write_trajectories(dir, &pool.name, &scen, &results)?;
    }
    let mut per_model = serde_json::Map::new();
    for r in &results {
        per_model.insert(r.model.name().to_string(), r.to_json(true));
    }
    Ok(json!({
        "pool": {"name": pool.name, "provenance": pool.provenance},
        "split": args.split,
        "params": doc.origin,
        "models_order": models.iter().map(|m| m.name()).collect::<Vec<_>>(),
        "models": per_model,
    }))
}

fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Writes `DIR/<scenario>.json`: every agent's record and each model's simulated tracks.
fn write_trajectories(
    dir: &Path,
    pool: &str,
    scenarios: &[Arc<Scenario>],
    results: &[ModelResult],
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    for (k, s) in scenarios.iter().enumerate() {
        let agents: Vec<Value> = s
            .agents
            .iter()
            .enumerate()
            .map(|(id, a)| {
                let fields = [
                    ("ego", json!(id == s.ego)),
                    ("recorded", json!(a.positions)),
                ];
                agent_json(id, a, fields)
            })
            .collect();
        let mut models = serde_json::Map::new();
        for r in results {
            let sr = &r.scenarios[k];
            let tracks: Vec<Value> = sr
                .simulated
                .as_deref()
                .unwrap_or_default()
                .iter()
                .map(|(id, t)| {
                    json!({
                        "id": id,
                        "start_step": s.agents[*id as usize].start_step,
                        "positions": t,
                    })
                })
                .collect();
            models.insert(
                r.model.name().to_string(),
                json!({"ade": sr.ade, "fde": sr.fde, "collided": sr.collided, "tracks": tracks}),
            );
        }
        let doc = json!({
            "pool": pool,
            "scenario": s.name,
            "split": s.split,
            "dt": s.dt,
            "agents": agents,
            "models": models,
        });
        let path = dir.join(format!("{}.json", sanitize(&s.name)));
        std::fs::write(&path, serde_json::to_string(&doc).expect("serializable"))
            .map_err(|e| format!("writing {}: {e}", path.display()))?;
    }
    Ok(())
}

/// Batch mode: one parameter document per input line, one result line per input line.
pub fn run_batch(
    args: &EvalPedsArgs,
    input: impl BufRead,
    mut output: impl Write,
) -> Result<(), String> {
    if args.params_json.as_deref() == Some("-") {
        return Err("--batch reads standard input: --params-json - cannot be used with it".into());
    }
    if args.trajectories.is_some() || args.out.is_some() {
        return Err(
            "--batch writes result lines to standard output: no --out/--trajectories".into(),
        );
    }
    let pool = load_pool(args.pool.as_deref())?;
    let scen = select_scenarios(&pool, &args.split, args.scenarios.as_deref(), args.limit)?;
    let models = parse_models(&args.models)?;
    let base = base_doc(args)?;
    let threads = threads(args);
    for (index, line) in input.lines().enumerate() {
        let line = line.map_err(|e| format!("reading standard input: {e}"))?;
        if line.trim().is_empty() {
            continue;
        }
        let result = (|| {
            let top = ParamsDoc::parse(&line, &format!("batch line {}", index + 1))
                .map_err(|e| e.to_string())?;
            let mut doc = base.clone();
            doc.overlay(&top);
            let params = params_for_models(&doc, &models)?;
            evaluate_models(&scen, &models, &params, false, threads)
        })();
        let out = match result {
            Ok(results) => {
                let mut per_model = serde_json::Map::new();
                for r in &results {
                    per_model.insert(r.model.name().to_string(), r.to_json(false));
                }
                json!({"index": index, "models": per_model})
            }
            Err(e) => json!({"index": index, "error": e}),
        };
        writeln!(output, "{out}").map_err(|e| format!("writing standard output: {e}"))?;
        output
            .flush()
            .map_err(|e| format!("writing standard output: {e}"))?;
    }
    Ok(())
}

/// The `eval-peds` subcommand.
pub fn run(args: &EvalPedsArgs) -> Result<(), String> {
    if args.batch {
        let stdin = std::io::stdin();
        return run_batch(args, stdin.lock(), std::io::stdout().lock());
    }
    let summary = run_summary(args)?;
    let text = serde_json::to_string_pretty(&summary).expect("serializable");
    match &args.out {
        Some(path) => {
            if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)
                    .map_err(|e| format!("creating {}: {e}", parent.display()))?;
            }
            std::fs::write(path, text + "\n")
                .map_err(|e| format!("writing {}: {e}", path.display()))?;
            for name in summary["models_order"].as_array().into_iter().flatten() {
                let m = &summary["models"][name.as_str().unwrap_or_default()];
                println!(
                    "{:<7} ADE {:.4}  FDE {:.4}  CR {:.4}  ({} episodes)",
                    name.as_str().unwrap_or_default(),
                    m["ade"].as_f64().unwrap_or(f64::NAN),
                    m["fde"].as_f64().unwrap_or(f64::NAN),
                    m["collision_rate"].as_f64().unwrap_or(f64::NAN),
                    m["episodes"]
                );
            }
        }
        None => println!("{text}"),
    }
    Ok(())
}
