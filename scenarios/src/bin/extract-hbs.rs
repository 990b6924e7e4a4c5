//! Extract a scenario pool from an HBS CSV.
//!
//! Usage: `extract-hbs --csv PATH --pool paper|general --out PATH`
//! (`--out -` writes to standard output). The output is deterministic; see `EXTRACTION.md`.

use std::process::ExitCode;

use scenarios::hbs::{extract_general, extract_paper, parse_hbs, GeneralParams, PaperParams};
use scenarios::pool::{validate_pool, OverlapCheck};
use scenarios::save_pool;
use sim_core::scenario::Split;

const USAGE: &str = "usage: extract-hbs --csv PATH --pool paper|general --out PATH";

fn run() -> Result<(), String> {
    let mut csv = None;
    let mut pool = None;
    let mut out = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let slot = match a.as_str() {
            "--csv" => &mut csv,
            "--pool" => &mut pool,
            "--out" => &mut out,
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            other => return Err(format!("unknown argument `{other}`\n{USAGE}")),
        };
        *slot = Some(
            args.next()
                .ok_or_else(|| format!("{a} needs a value\n{USAGE}"))?,
        );
    }
    let (Some(csv), Some(kind), Some(out)) = (csv, pool, out) else {
        return Err(USAGE.to_string());
    };
    let bytes = std::fs::read(&csv).map_err(|e| format!("{csv}: {e}"))?;
    let data = parse_hbs(&bytes).map_err(|e| format!("{csv}: {e}"))?;
    let (pool, check) = match kind.as_str() {
        "paper" => (
            extract_paper(&data, &PaperParams::default()),
            OverlapCheck::AllSteps,
        ),
        "general" => (
            extract_general(&data, &GeneralParams::default()),
            OverlapCheck::Spawn,
        ),
        other => return Err(format!("unknown pool `{other}`\n{USAGE}")),
    };
    validate_pool(&pool, &out, check).map_err(|e| format!("extracted pool is invalid: {e}"))?;
    let text = save_pool(&pool);
    if out == "-" {
        print!("{text}");
    } else {
        std::fs::write(&out, &text).map_err(|e| format!("{out}: {e}"))?;
    }
    let test = pool.split(Split::Test).count();
    eprintln!(
        "{}: {} scenarios ({} train, {} test), {} bytes",
        pool.name,
        pool.scenarios.len(),
        pool.scenarios.len() - test,
        test,
        text.len()
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("extract-hbs: {e}");
            ExitCode::FAILURE
        }
    }
}
