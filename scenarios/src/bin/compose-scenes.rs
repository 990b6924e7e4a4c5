//! Write composed scenes (`scenarios::composed`) as a pool file.
//!
//! Usage: `compose-scenes --pool PATH|embedded:NAME --scenes N [--seed S] [--first I]
//! [--pedestrians K] [--hold-out NAME,NAME,...] [--no-other-cars] --out PATH`
//! (`--out -` writes to standard output). Scene `i` of the file is composed scene `first + i`
//! of seed `S`, the very scene a server's env of the same request plays; every scene is in the
//! `train` split. The pool keeps the source's vehicle model.

use std::process::ExitCode;
use std::time::Instant;

use scenarios::composed::{ComposeConfig, Parts};
use scenarios::pool::{validate_pool, OverlapCheck};
use scenarios::save_pool;
use sim_core::scenario::{ScenarioPool, SCENARIO_FORMAT_VERSION};

const USAGE: &str = "usage: compose-scenes --pool PATH|embedded:NAME --scenes N [--seed S] \
[--first I] [--pedestrians K] [--hold-out NAME,...] [--no-other-cars] --out PATH";

fn number<T: std::str::FromStr>(flag: &str, value: &str) -> Result<T, String> {
    value
        .parse()
        .map_err(|_| format!("{flag} {value:?}: not a whole number\n{USAGE}"))
}

fn run() -> Result<(), String> {
    let (mut pool, mut out, mut scenes) = (None, None, None);
    let (mut first, mut hold_out) = (0u64, Vec::new());
    let mut config = ComposeConfig::default();
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        if flag == "-h" || flag == "--help" {
            println!("{USAGE}");
            return Ok(());
        }
        if flag == "--no-other-cars" {
            config.other_cars = false;
            continue;
        }
        let value = args
            .next()
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
        match flag.as_str() {
            "--pool" => pool = Some(value),
            "--out" => out = Some(value),
            "--scenes" => scenes = Some(number::<u64>(&flag, &value)?),
            "--seed" => config.seed = number(&flag, &value)?,
            "--first" => first = number(&flag, &value)?,
            "--pedestrians" => config.pedestrians = Some(number(&flag, &value)?),
            "--hold-out" => hold_out = value.split(',').map(String::from).collect(),
            other => return Err(format!("unknown argument `{other}`\n{USAGE}")),
        }
    }
    let (Some(pool), Some(out), Some(scenes)) = (pool, out, scenes) else {
        return Err(USAGE.to_string());
    };
    config.validate().map_err(|e| e.to_string())?;
    let source = scenarios::embedded::pool_from_arg(pool.as_ref())?;
    let parts = Parts::new(&source, &hold_out).map_err(|e| e.to_string())?;
    let clock = Instant::now();
    let composed = ScenarioPool {
        version: SCENARIO_FORMAT_VERSION,
        name: format!("{}-composed-s{}", source.name, config.seed),
        provenance: format!(
            "scenes {first}..{} composed (scenarios::composed, seed {}) from the train scenes of \
             {} less {} held out: {}",
            first + scenes,
            config.seed,
            source.name,
            hold_out.len(),
            source.provenance
        ),
        vehicle_model: source.vehicle_model,
        scenarios: (first..first + scenes)
            .map(|i| parts.compose(&config, i))
            .collect(),
    };
    let seconds = clock.elapsed().as_secs_f64();
    validate_pool(&composed, &out, OverlapCheck::Spawn)
        .map_err(|e| format!("a composed scene is invalid: {e}"))?;
    let text = save_pool(&composed);
    if out == "-" {
        print!("{text}");
    } else {
        std::fs::write(&out, &text).map_err(|e| format!("{out}: {e}"))?;
    }
    let (routes, tracks, meetings) = parts.counts();
    eprintln!(
        "{scenes} scenes from {routes} routes, {tracks} pedestrian tracks and {meetings} \
         meetings of {}; {:.1} µs a scene",
        source.name,
        seconds * 1e6 / scenes.max(1) as f64
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
