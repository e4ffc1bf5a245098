//! `remove_prefix_leftovers` removes what a process killed without cleanup leaves under its
//! prefix, the node's own directory included: iceoryx2 names that directory by the node's id,
//! and only the files in it carry the prefix.

use std::path::PathBuf;

use iceoryx2::prelude::*;

const NODES_DIR: &str = "/tmp/iceoryx2/nodes";

/// The node directories holding an entry whose name starts with `prefix`.
fn node_dirs_of(prefix: &str) -> Vec<PathBuf> {
    let Ok(nodes) = std::fs::read_dir(NODES_DIR) else {
        return Vec::new();
    };
    nodes
        .flatten()
        .filter(|node| {
            std::fs::read_dir(node.path()).is_ok_and(|mut entries| {
                entries
                    .any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().starts_with(prefix)))
            })
        })
        .map(|node| node.path())
        .collect()
}

#[test]
fn the_node_directory_of_a_process_that_never_cleaned_up_is_removed() {
    let prefix = format!("cleft{}_", std::process::id());
    let mut config = iceoryx2::config::Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
    let node = NodeBuilder::new()
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .unwrap();
    let service = node
        .service_builder(&ServiceName::new("leftovers/test").unwrap())
        .event()
        .open_or_create()
        .unwrap();
    // As a killed process would: nothing of the node is dropped, so nothing is cleaned up.
    std::mem::forget(service);
    std::mem::forget(node);
    let left = node_dirs_of(&prefix);
    assert_eq!(left.len(), 1, "the node left no directory: {left:?}");

    let removed = ppfd_client::remove_prefix_leftovers(&prefix).unwrap();

    assert!(removed > 0);
    assert_eq!(node_dirs_of(&prefix), Vec::<PathBuf>::new());
    assert!(!left[0].exists(), "{} is still there", left[0].display());
    let other = std::fs::read_dir("/tmp/iceoryx2/services")
        .into_iter()
        .flatten()
        .flatten()
        .chain(
            std::fs::read_dir("/dev/shm")
                .into_iter()
                .flatten()
                .flatten(),
        )
        .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
        .map(|e| e.path())
        .collect::<Vec<_>>();
    assert_eq!(other, Vec::<PathBuf>::new());
}
