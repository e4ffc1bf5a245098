//! The `ppfd` daemon as the end-to-end tests run it: the same command line, with the engine
//! chosen by `PPFD_TEST_ENGINE` (`fake` for transport tests, otherwise the PPF engine).

use std::process::ExitCode;
use std::sync::Arc;

fn main() -> ExitCode {
    ppfd::cli::main(Box::new(|config| {
        Ok(match std::env::var("PPFD_TEST_ENGINE").as_deref() {
            Ok("fake") => Arc::new(ppfd_tests::FakeEngine::from_env()),
            _ => Arc::new(ppfd::ppf_engine::PpfEngine::from_config(config)?),
        })
    }))
}
