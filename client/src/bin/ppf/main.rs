//! `ppf`: the ppfd command line.

mod model;
mod score;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "ppf",
    version,
    about = "ppfd command line: models, detection, evaluation"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Build and inspect object model files.
    #[command(subcommand)]
    Model(model::ModelCommand),
    /// Score a BOP results CSV against a dataset (BOP 2018 recall, BOP 2019 AR).
    Score(score::ScoreArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Model(cmd) => model::run(cmd),
        Command::Score(args) => score::run(args),
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
