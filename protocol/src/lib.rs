//! The ppfd wire contract.
