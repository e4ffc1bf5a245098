use std::process::ExitCode;
use std::sync::Arc;

use ppfd::ppf_engine::PpfEngine;

fn main() -> ExitCode {
    ppfd::cli::main(Box::new(|config| {
        Ok(Arc::new(PpfEngine::from_config(config)?) as Arc<dyn ppfd::DetectionEngine>)
    }))
}
