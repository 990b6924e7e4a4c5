//! `sim-server`: the sharedspace command line. Thin: parses arguments, sets up logging, and
//! calls into the library.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use clap::{Parser, Subcommand};
use sim_core::params::{PedestrianModel, VehicleModel};
use sim_core::scenario::ScenarioPool;
use sim_core::variation::VariationSpec;
use sim_server::params_file::ParamsDoc;
use sim_server::rollout::{rollout_driving, DrivenPedestrian, EgoDrive, RolloutModels};

#[derive(Parser, Debug)]
#[command(
    name = "sim-server",
    version,
    about = "sharedspace: shared-space AV/pedestrian simulation"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run one scenario and write every step as JSON lines (see docs/ROLLOUT.md).
    Rollout(RolloutArgs),
    /// Time one full world step (1 AV + N CR-SFM pedestrians at 0.25 /m²) and print JSON.
    BenchStep(BenchStepArgs),
    /// Evaluate pedestrian models against the record (paper Table I; docs/RESULTS.md).
    EvalPeds(sim_server::pedeval_cmd::EvalPedsArgs),
    /// Serve simulation envs over zenoh (protocol/SPEC.md); stops on SIGINT or SIGTERM.
    Serve(ServeArgs),
    /// Run a zenoh router (deploy/router.json5: auth, TLS, access control) until SIGINT or
    /// SIGTERM, so a deployment needs no separately installed zenohd (deploy/README.md).
    Router(RouterArgs),
    /// Write a pool of synthetic scenes (crowd layouts, N pedestrians, V vehicles, seeds) as a
    /// scenario file (scenarios/FORMAT.md) to serve (`serve --cfg 'pools:["FILE"]'`) or roll out.
    /// Envs can also ask for such scenes directly (`CreateEnv.synthetic`, protocol/SPEC.md).
    Synth(SynthArgs),
}

#[derive(clap::Args, Debug)]
struct SynthArgs {
    /// Layout: `crossing` (pedestrians cross the vehicle's path), `counter_flow` (they walk
    /// towards it) or `random`.
    #[arg(long, default_value = "crossing")]
    layout: String,
    /// Pedestrians per scene.
    #[arg(long, default_value_t = 50)]
    pedestrians: usize,
    /// Vehicles per scene: the ego and `V - 1` others on parallel lanes 4 m apart.
    #[arg(long, default_value_t = 1)]
    vehicles: usize,
    /// Pedestrians per square metre of the crowd's square.
    #[arg(long, default_value_t = 0.25)]
    density: f64,
    /// Seed of the first scene; scene i has seed + i.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Number of scenes; split like the HBS pools (scene i is a test scene when i mod 13 is 2, 6
    /// or 10).
    #[arg(long, default_value_t = 13)]
    scenes: u64,
    /// Pool name (what `CreateEnv.pool` names).
    #[arg(long, default_value = "synthetic")]
    name: String,
    /// Output file; `-` writes to standard output.
    #[arg(long)]
    out: PathBuf,
}

fn run_synth(a: SynthArgs) -> Result<(), String> {
    use scenarios::synthetic::{generate_pool, SyntheticConfig};
    let layout = a.layout.parse().map_err(|e| format!("--layout: {e}"))?;
    let configs: Vec<SyntheticConfig> = (0..a.scenes)
        .map(|i| SyntheticConfig {
            layout,
            pedestrians: a.pedestrians,
            vehicles: a.vehicles,
            density: a.density,
            seed: a.seed.wrapping_add(i),
            split: scenarios::hbs::split_for(i as usize),
            ..SyntheticConfig::default()
        })
        .collect();
    let pool = generate_pool(&a.name, &configs).map_err(|e| e.to_string())?;
    let text = scenarios::save_pool(&pool);
    if a.out.as_os_str() == "-" {
        print!("{text}");
    } else {
        std::fs::write(&a.out, &text).map_err(|e| format!("{}: {e}", a.out.display()))?;
        eprintln!(
            "{}: {} scenes ({} test) of {} pedestrians and {} vehicle(s)",
            a.out.display(),
            pool.scenarios.len(),
            pool.scenarios
                .iter()
                .filter(|s| s.split == sim_core::scenario::Split::Test)
                .count(),
            a.pedestrians,
            a.vehicles
        );
    }
    Ok(())
}

#[derive(clap::Args, Debug)]
struct ServeArgs {
    /// Server configuration (JSON5, see deploy/server.json5); defaults when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override one configuration value: `KEY:VALUE` with a `/`-separated KEY and a JSON5 VALUE,
    /// e.g. `--cfg capacity:64 --cfg 'zenoh/mode:"client"'`. Repeatable.
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    cfg: Vec<String>,
}

/// The runtime of `serve` and `router`: multi-threaded, as zenoh needs.
fn multi_thread_runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("starting the tokio runtime: {e}"))
}

fn run_serve(args: ServeArgs) -> Result<(), String> {
    let config = sim_server::server::ServerConfig::load(args.config.as_deref(), &args.cfg)
        .map_err(|e| e.to_string())?;
    sim_server::server::limit_allocator_arenas(config.malloc_arenas);
    let runtime = multi_thread_runtime()?;
    runtime
        .block_on(sim_server::server::run(
            config,
            sim_server::server::shutdown_signal(),
        ))
        .map_err(|e| e.to_string())
}

#[derive(clap::Args, Debug)]
struct RouterArgs {
    /// Zenoh router configuration (JSON5, zenoh's format; see deploy/router.json5). Absent:
    /// zenoh's router defaults (listen on tcp/[::]:7447), multicast scouting off.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override one configuration value: `KEY:VALUE` with a `/`-separated KEY and a JSON5 VALUE,
    /// e.g. `--cfg 'listen/endpoints:["tcp/0.0.0.0:7447"]'`. Repeatable.
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    cfg: Vec<String>,
}

fn run_router(args: RouterArgs) -> Result<(), String> {
    let config = sim_server::router::load_config(args.config.as_deref(), &args.cfg)
        .map_err(|e| e.to_string())?;
    let runtime = multi_thread_runtime()?;
    runtime
        .block_on(sim_server::router::run(
            &config,
            sim_server::server::shutdown_signal(),
        ))
        .map_err(|e| e.to_string())
}

#[derive(clap::Args, Debug)]
struct BenchStepArgs {
    /// Number of pedestrians.
    #[arg(long)]
    n: usize,
    /// Seconds of stepping to average over.
    #[arg(long, default_value_t = 2.0)]
    seconds: f64,
    /// Scene seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Vehicles: the AV and `V - 1` others on parallel lanes through the crowd.
    #[arg(long, default_value_t = 1)]
    vehicles: usize,
    /// How the other vehicles move: `replay` or `idm`.
    #[arg(long, default_value = "replay", value_parser = vehicle_model_names())]
    vehicle_model: String,
}

#[derive(clap::Args, Debug)]
struct PoolArgs {
    /// Scenario pool file (JSON, scenarios/FORMAT.md) or an embedded pool,
    /// `embedded:hbs-paper` or `embedded:hbs-general`; `hbs-paper` when absent.
    #[arg(long)]
    pool: Option<PathBuf>,
    /// World-parameter file (JSON5, any subset of the fields of docs/PARAMETERS.md); the shipped
    /// calibrated parameters when absent, model.md's starting values with `spec`.
    #[arg(long)]
    params: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct RolloutArgs {
    #[command(flatten)]
    pool: PoolArgs,
    /// Scenario name, or its index in the pool.
    #[arg(long, default_value = "0")]
    scenario: String,
    /// Pedestrian model.
    #[arg(long, default_value = "cr_sfm", value_parser = model_names())]
    model: String,
    /// How the vehicles nobody controls move: `replay` or `idm` (docs/MODEL.md "Traffic");
    /// default: as the pool says (`hbs-general`: idm, others: replay).
    #[arg(long, value_parser = vehicle_model_names())]
    vehicles: Option<String>,
    /// `replay` (the AV follows its record) or a constant normalised action `ACC,YAW_RATE` in [-1, 1].
    #[arg(long, default_value = "replay")]
    av: String,
    /// Drive `pedestrian_K` (the scene's pedestrians in agent order) like an external agent
    /// holding the normalised acceleration `F,L` along and to the left of its heading
    /// (docs/MODEL.md 2b): `K=F,L`; repeatable.
    #[arg(long = "pedestrian", value_name = "K=F,L")]
    pedestrians: Vec<String>,
    /// Output file; standard output when absent.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Threads a step may use: scenes of at least 512 agents are split over them, with the same
    /// output for every count.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=256))]
    threads: u16,
    /// Play the scene variation of this seed (a reset result's `variation.seed`): the episode a
    /// server env with the same variations played.
    #[arg(long)]
    variation: Option<u64>,
    /// The variations (JSON, `CreateEnv.variations`' fields) that `--variation` draws from;
    /// default: the benchmark's (position_sigma 0.25, start_offset_steps 1,
    /// desired_speed_scale 0.1).
    #[arg(long, requires = "variation")]
    variations: Option<String>,
}

fn load_pool(args: &PoolArgs) -> Result<ScenarioPool, String> {
    match &args.pool {
        Some(path) => scenarios::embedded::pool_from_arg(path),
        None => Ok(scenarios::embedded::default_pool()),
    }
}

/// The pedestrian models' names, as a clap parser (the help lists them).
fn model_names() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(PedestrianModel::ALL.map(|m| m.name()))
}

/// The vehicle models' names, as a clap parser.
fn vehicle_model_names() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(VehicleModel::ALL.map(|m| m.name()))
}

fn parse_model(name: &str) -> Result<PedestrianModel, String> {
    PedestrianModel::from_name(name).ok_or_else(|| {
        format!(
            "unknown pedestrian model `{name}` (expected {})",
            PedestrianModel::names()
        )
    })
}

fn parse_ego(text: &str) -> Result<EgoDrive, String> {
    if text == "replay" {
        return Ok(EgoDrive::Replay);
    }
    let parts: Vec<&str> = text.split(',').collect();
    let parse = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    match parts.as_slice() {
        [a, b] => match (parse(a), parse(b)) {
            (Some(a), Some(b)) => Ok(EgoDrive::Constant([a, b])),
            _ => Err(format!(
                "--av `{text}`: expected two finite numbers ACC,YAW_RATE"
            )),
        },
        _ => Err(format!("--av `{text}`: expected `replay` or ACC,YAW_RATE")),
    }
}

fn parse_walker(text: &str) -> Result<DrivenPedestrian, String> {
    let bad = || format!("--pedestrian `{text}`: expected K=F,L (an index, two finite numbers)");
    let (k, action) = text.split_once('=').ok_or_else(bad)?;
    let index = k.trim().parse::<usize>().map_err(|_| bad())?;
    let parse = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    match action.split(',').collect::<Vec<_>>().as_slice() {
        [f, l] => match (parse(f), parse(l)) {
            (Some(f), Some(l)) => Ok(DrivenPedestrian {
                index,
                action: [f, l],
            }),
            _ => Err(bad()),
        },
        _ => Err(bad()),
    }
}

fn run_rollout(args: RolloutArgs) -> Result<(), String> {
    let pool = load_pool(&args.pool)?;
    let model = parse_model(&args.model)?;
    let params = ParamsDoc::from_arg(args.pool.params.as_deref())
        .and_then(|doc| doc.world_params(Some(model)))
        .map_err(|e| e.to_string())?;
    let ego = parse_ego(&args.av)?;
    let walkers = args
        .pedestrians
        .iter()
        .map(|t| parse_walker(t))
        .collect::<Result<Vec<_>, _>>()?;
    let scenario = pool
        .scenarios
        .iter()
        .find(|s| s.name == args.scenario)
        .or_else(|| {
            args.scenario
                .parse::<usize>()
                .ok()
                .and_then(|k| pool.scenarios.get(k))
        })
        .ok_or_else(|| format!("no scenario `{}` in pool `{}`", args.scenario, pool.name))?;
    let variation = match args.variation {
        None => None,
        Some(seed) => {
            let spec = match &args.variations {
                None => VariationSpec::benchmark(),
                Some(text) => serde_json::from_str::<VariationSpec>(text)
                    .map_err(|e| format!("--variations: {e}"))?,
            };
            spec.validate().map_err(|e| format!("--variations: {e}"))?;
            Some(spec.draw(scenario, &params, seed))
        }
    };
    let scenario = Arc::new(scenario.clone());
    let threads = usize::from(args.threads);
    let mut out: Box<dyn std::io::Write> = match &args.out {
        Some(path) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(path).map_err(|e| format!("creating {}: {e}", path.display()))?,
        )),
        None => Box::new(std::io::stdout().lock()),
    };
    let vehicles = match &args.vehicles {
        Some(name) => VehicleModel::from_name(name).ok_or_else(|| {
            format!(
                "unknown vehicle model `{name}` (expected {})",
                VehicleModel::names()
            )
        })?,
        None => pool.vehicle_model,
    };
    let models = RolloutModels {
        pedestrians: model,
        vehicles,
    };
    rollout_driving(
        scenario,
        params,
        models,
        ego,
        &walkers,
        variation.as_ref(),
        threads,
        &mut out,
    )
    .map(|_| ())
    .map_err(|e| e.to_string())
}

#[cfg(jemalloc_allocator)]
#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

fn main() -> ExitCode {
    // Without RUST_LOG: warnings, and the server's and router's own info lines (the line that
    // says a server serves: its id, endpoints and pools).
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,sim_server=info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    let result = match args.command {
        Command::Rollout(a) => run_rollout(a),
        Command::EvalPeds(a) => sim_server::pedeval_cmd::run(&a),
        Command::Serve(a) => run_serve(a),
        Command::Router(a) => run_router(a),
        Command::Synth(a) => run_synth(a),
        Command::BenchStep(a) => {
            let model = VehicleModel::from_name(&a.vehicle_model).expect("checked by clap");
            let (ns, edges, steps) = sim_server::step_timing::time_traffic_steps(
                a.n, a.seed, a.vehicles, model, a.seconds, 10,
            );
            println!(
                "{}",
                serde_json::json!({"n": a.n, "vehicles": a.vehicles, "vehicle_model": a.vehicle_model,
                    "ns_per_step": ns, "edges": edges, "steps": steps})
            );
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
