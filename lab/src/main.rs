//! `gonio-lab`: the research commands on the gonio library: the trade-off and planner reports,
//! encoder datasets, training (feature `train`) and the encoder's accuracy report.

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::process::ExitCode;

mod cli {
    pub mod encoder;
    pub mod peer;
    pub mod plan;

    use clap::builder::{PossibleValuesParser, TypedValueParser};
    use std::str::FromStr;
    use strum::VariantNames;

    /// Parse one of the library enum `T`'s names (kebab-case), listing them in `--help`.
    pub fn parse_name<T>() -> impl TypedValueParser<Value = T>
    where
        T: FromStr + VariantNames + Clone + Send + Sync + 'static,
        T::Err: std::error::Error + Send + Sync + 'static,
    {
        PossibleValuesParser::new(T::VARIANTS).try_map(|s| s.parse::<T>())
    }
}

#[derive(Parser)]
#[command(
    name = "gonio-lab",
    version = gonio::VERSION,
    about = "The gonio lab: planner and encoder studies on the gonio library"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Accuracy vs time: strategies, levels, stopping rules, spacings and orders on a set of materials.
    PlanReport(cli::plan::PlanReportArgs),
    /// Accuracy vs measurement time per strategy and level (adaptive, adaptive-true, specular, uniform); --preset table1.
    Tradeoff(cli::plan::TradeoffArgs),
    /// The closed loop in simulation: its error estimate, calibration, stop rules against the
    /// oracle, and closed loop / uniform at equal directions (--preset training|heldout|real).
    ClosedLoop(cli::plan::ClosedLoopArgs),
    /// The closed loop's stop rule replayed on runs' rows, its ratio chosen on a training run's.
    StopReplay(cli::plan::StopReplayArgs),
    /// The nielsen2015 peer side by side with adaptive and uniform, held-out MERL and the real measurements.
    Peer(cli::peer::PeerArgs),
    /// Render an encoder dataset (examples/capture.toml with random or MERL materials).
    Dataset(cli::encoder::DatasetArgs),
    /// Train an encoder on a dataset and write ONNX (needs `--features train`).
    Train(cli::encoder::TrainArgs),
    /// An encoder's accuracy on a dataset's test images, across light intensities.
    EncoderReport(cli::encoder::ReportArgs),
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::PlanReport(args) => cli::plan::run_plan_report(args),
        Command::Tradeoff(args) => cli::plan::run_tradeoff(args),
        Command::ClosedLoop(args) => cli::plan::run_closed_loop(args),
        Command::StopReplay(args) => cli::plan::run_stop_replay(args),
        Command::Peer(args) => cli::peer::run_peer(args),
        Command::Dataset(args) => cli::encoder::run_dataset(args),
        Command::Train(args) => cli::encoder::run_train(args),
        Command::EncoderReport(args) => cli::encoder::run_report(args),
    }
}
