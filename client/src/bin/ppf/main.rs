//! `ppf`: the ppfd command line.

mod detect_offline;
mod model;
mod offline;

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
    /// Detect objects in one frame of a BOP dataset (offline, in this process).
    Detect(detect_offline::DatasetDetectArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Model(cmd) => model::run(cmd),
        Command::Detect(args) => detect_offline::run(args),
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
