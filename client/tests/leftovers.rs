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

/// A node with a service under `prefix`, left as a killed process leaves it: nothing of it is
/// dropped, so nothing is cleaned up.
fn abandoned_node(prefix: &str) {
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
    std::mem::forget(service);
    std::mem::forget(node);
}

/// The names in the services folder and `/dev/shm` that start with `prefix`.
fn entries(prefix: &str) -> Vec<String> {
    let mut names: Vec<String> = ["/tmp/iceoryx2/services", "/dev/shm"]
        .into_iter()
        .filter_map(|dir| std::fs::read_dir(dir).ok())
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(prefix))
        .collect();
    names.sort();
    names
}

#[test]
fn the_node_directory_of_a_process_that_never_cleaned_up_is_removed() {
    let prefix = format!("cleft{}_", std::process::id());
    // Another cell's prefix, which starts with this one: its entries are not this prefix's.
    let longer = format!("{prefix}1_");
    abandoned_node(&prefix);
    abandoned_node(&longer);
    let left = node_dirs_of(&prefix);
    assert_eq!(left.len(), 2, "the nodes left no directories: {left:?}");
    let longer_dir = node_dirs_of(&longer);
    assert_eq!(longer_dir.len(), 1, "{longer_dir:?}");

    let removed = ppfd_client::remove_prefix_leftovers(&prefix).unwrap();

    assert!(removed > 0);
    // Only the longer prefix's node and entries are left, whole.
    assert_eq!(node_dirs_of(&prefix), longer_dir);
    let theirs = entries(&longer);
    assert!(!theirs.is_empty());
    assert_eq!(entries(&prefix), theirs);

    ppfd_client::remove_prefix_leftovers(&longer).unwrap();
    assert_eq!(node_dirs_of(&prefix), Vec::<PathBuf>::new());
    assert_eq!(entries(&prefix), Vec::<String>::new());
}

/// A prefix whose daemon runs is refused and its files are left: removing them would cut the
/// daemon off from its clients and cameras. Once the daemon's node is gone, the same call goes
/// through.
#[test]
fn a_prefix_a_running_daemon_serves_is_refused() {
    let prefix = format!("cserved{}_", std::process::id());
    let mut config = iceoryx2::config::Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
    let daemon = NodeBuilder::new()
        .name(&NodeName::new(ppfd_protocol::services::DAEMON_NODE).unwrap())
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .unwrap();
    let service = daemon
        .service_builder(&ServiceName::new("leftovers/served").unwrap())
        .event()
        .open_or_create()
        .unwrap();
    let before = entries(&prefix);
    assert!(!before.is_empty());
    let e = ppfd_client::remove_prefix_leftovers(&prefix).unwrap_err();
    assert_eq!(
        e.to_string(),
        format!(
            "a ppfd daemon is running under the iceoryx2 prefix {prefix:?}: its files are removed \
             only after it has stopped, or its clients and cameras could no longer reach it"
        )
    );
    assert_eq!(entries(&prefix), before);
    drop(service);
    drop(daemon);
    ppfd_client::remove_prefix_leftovers(&prefix).unwrap();
    assert_eq!(entries(&prefix), Vec::<String>::new());
}
