//! ppfd client library.
