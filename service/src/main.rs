use std::process::ExitCode;
use std::sync::Arc;

fn main() -> ExitCode {
    ppfd::cli::main(Arc::new(ppfd::ppf_engine::PpfEngine::default()))
}
