//! Dead-process cleanup and camera discovery, on a thread of their own.
//!
//! Both walk iceoryx2's directories — every node's, every service's — and take milliseconds
//! (2–4 ms measured with a few hundred node entries left by earlier processes). On the I/O
//! thread that time would be a stall once a second: a request arriving during it would wait, and
//! show up as milliseconds of transport in the latency tail. The housekeeper has its own iceoryx2
//! node, wakes every period (or at once when asked, e.g. when a camera announces itself), and
//! hands the camera names it finds to the I/O thread over a channel, waking it through the
//! same eventfd the workers use.

use std::sync::mpsc::{channel, sync_channel, Receiver, RecvTimeoutError, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::node::{NodeCleanupFailure, NodeView};
use iceoryx2::prelude::*;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern;

use ppfd_protocol::services;

use crate::error::{resource, Error, Result};
use crate::wakeup::Signaller;

type Ipc = ipc::Service;

/// The cleanup of processes that died without removing their iceoryx2 resources. iceoryx2's own
/// cleanup counts a dead node as cleaned up even when it leaves some of its entries (a process
/// killed in its first milliseconds, before it wrote its node's details): such a node is listed
/// as dead again at every round, and would be logged as "removed" once a second for as long as
/// the daemon runs. Here each dead node is cleaned up once; one still listed at a later round, or
/// one iceoryx2 finds nothing of to clean up, has what is left of it removed by name: its
/// monitor files and its entries in its node folder.
#[derive(Default)]
pub struct DeadNodes {
    /// Nodes cleaned up before, still listed at the last round.
    cleaned: std::collections::HashSet<u128>,
    /// Node folders holding another prefix's entries, still present at the last round: a node
    /// belongs to one prefix, so they are not read again.
    foreign: std::collections::HashSet<u128>,
    /// Listeners of the prefix, older than [`ORPHAN_AGE`], by port id, and the port tag found
    /// for each: checked alone at later rounds, not looked for in every node's folder.
    tagged: std::collections::HashMap<u128, std::path::PathBuf>,
}

/// What one round of [`DeadNodes::sweep`] did.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Sweep {
    /// Dead nodes cleaned up by iceoryx2.
    pub cleaned: u64,
    /// Dead nodes whose cleanup failed (another process may be at it).
    pub failed: u64,
    /// Nodes cleaned up before that were still listed: what was left of them is removed.
    pub leftovers: u64,
    /// Listeners of no port whose socket or segment went: a process killed while it made a
    /// listener.
    pub listeners: u64,
    /// Empty segments met: with young ones left, iceoryx2's cleanup waits for the next round.
    pub unfinished: Unfinished,
}

impl Sweep {
    /// Logs what the round removed (`info`) and what it could not clean up (`debug`);
    /// `message` says when it ran.
    pub fn log(&self, message: &str) {
        if self.cleaned + self.leftovers + self.listeners > 0 {
            tracing::info!(
                removed = self.cleaned,
                leftovers = self.leftovers,
                listeners = self.listeners,
                "{message}"
            );
        }
        if self.failed > 0 {
            tracing::debug!(failed = self.failed, "dead processes not cleaned up");
        }
    }
}

impl DeadNodes {
    /// Cleans up the dead nodes under `config`'s prefix.
    pub fn sweep(&mut self, config: &iceoryx2::config::Config) -> Sweep {
        let mut segments = segments_of(config);
        let mut sweep = Sweep {
            unfinished: remove_unfinished_segments(&mut segments),
            ..Sweep::default()
        };
        let wait = sweep.unfinished.young > 0;
        let mut listed = std::collections::HashSet::new();
        let mut again = Vec::new();
        let mut all = std::collections::HashSet::new();
        let listing = Node::<Ipc>::list(config, |state| {
            all.insert(match &state {
                NodeState::Alive(v) => v.id().value(),
                NodeState::Dead(v) => v.id().value(),
                NodeState::Inaccessible(id) | NodeState::Undefined(id) => id.value(),
            });
            if let NodeState::Dead(view) = state {
                let id = view.id().value();
                listed.insert(id);
                if self.cleaned.contains(&id) {
                    again.push(id);
                } else if !wait {
                    match view.try_remove_stale_resources() {
                        Ok(()) => {
                            sweep.cleaned += 1;
                            self.cleaned.insert(id);
                        }
                        // Listed as dead, yet iceoryx2 finds nothing of it to clean up.
                        Err(NodeCleanupFailure::ResourcesAlreadyCleanedUp) => again.push(id),
                        Err(_) => sweep.failed += 1,
                    }
                }
            }
            CallbackProgression::Continue
        });
        for id in again {
            if remove_node_leftovers(config, id) > 0 {
                sweep.leftovers += 1;
            }
        }
        if listing.is_ok() {
            sweep.leftovers += remove_orphan_nodes(config, &all, &mut self.foreign);
            sweep.listeners += remove_orphan_listeners(config, &segments, &mut self.tagged);
        }
        self.cleaned.retain(|id| listed.contains(id));
        sweep
    }
}

/// A monitor file this old whose node iceoryx2 does not list is an orphan, not a node being
/// made (that takes milliseconds).
const ORPHAN_AGE: Duration = Duration::from_secs(10);

/// Whether an entry was last changed `age` or longer ago.
fn older_than(metadata: &std::io::Result<std::fs::Metadata>, age: Duration) -> bool {
    metadata
        .as_ref()
        .ok()
        .and_then(|m| m.modified().ok())
        .and_then(|t| t.elapsed().ok())
        .is_some_and(|elapsed| elapsed >= age)
}

/// Removes what is left of nodes that iceoryx2 does not list at all (`listed`), older than
/// [`ORPHAN_AGE`]: a process killed while it made its node leaves some of its monitor files
/// (`<prefix><id>.node_monitor…`) without the one listing needs, or, killed earlier, only its
/// details file in its folder `<id>/`. Clients that crash in a loop would otherwise fill the
/// node directory, which every round reads. The folders of other prefixes' nodes are read
/// once and remembered in `foreign` while they exist. Returns how many nodes' files went.
fn remove_orphan_nodes(
    config: &iceoryx2::config::Config,
    listed: &std::collections::HashSet<u128>,
    foreign: &mut std::collections::HashSet<u128>,
) -> u64 {
    let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
    let prefix = config.global.prefix.to_string();
    let Ok(entries) = std::fs::read_dir(&nodes) else {
        return 0;
    };
    let mut orphans = std::collections::HashSet::new();
    let mut with_monitor = std::collections::HashSet::new();
    let mut folders = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.bytes().all(|b| b.is_ascii_digit()) {
            if let Ok(id) = name.parse::<u128>() {
                folders.push((id, e.path()));
            }
            continue;
        }
        if !services::is_entry_of_prefix(&name, &prefix) {
            continue;
        }
        let Some((id, kind)) = name
            .strip_prefix(&prefix)
            .and_then(|rest| rest.split_once('.'))
        else {
            continue;
        };
        let Ok(id) = id.parse::<u128>() else { continue };
        if kind.starts_with("node_monitor") {
            with_monitor.insert(id);
            if !listed.contains(&id) && older_than(&e.metadata(), ORPHAN_AGE) {
                orphans.insert(id);
            }
        }
    }
    // A folder holding entries of the prefix, all old, of a node without monitor files.
    let present: std::collections::HashSet<u128> = folders.iter().map(|(id, _)| *id).collect();
    foreign.retain(|id| present.contains(id));
    for (id, folder) in folders {
        if listed.contains(&id) || with_monitor.contains(&id) || foreign.contains(&id) {
            continue;
        }
        let Ok(inside) = std::fs::read_dir(&folder) else {
            continue;
        };
        let (ours, theirs): (Vec<_>, Vec<_>) = inside
            .flatten()
            .partition(|e| services::is_entry_of_prefix(&e.file_name().to_string_lossy(), &prefix));
        if ours.is_empty() {
            // Empty, it may be a node of this prefix being made: read again next round.
            if !theirs.is_empty() {
                foreign.insert(id);
            }
        } else if ours.iter().all(|e| older_than(&e.metadata(), ORPHAN_AGE)) {
            orphans.insert(id);
        }
    }
    orphans
        .into_iter()
        .filter(|&id| remove_node_leftovers(config, id) > 0)
        .count() as u64
}

/// An entry of the prefix in `/dev/shm`, as a round read it.
struct Segment {
    name: String,
    path: std::path::PathBuf,
    metadata: std::io::Result<std::fs::Metadata>,
}

/// The prefix's entries in `/dev/shm`, read once a round for the functions that look there.
fn segments_of(config: &iceoryx2::config::Config) -> Vec<Segment> {
    let prefix = config.global.prefix.to_string();
    std::fs::read_dir(services::SHARED_MEMORY_DIR)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            services::is_entry_of_prefix(&name, &prefix).then(|| Segment {
                name,
                path: e.path(),
                metadata: e.metadata(),
            })
        })
        .collect()
}

/// Empty shared memory segments of the prefix that a round met (`remove_unfinished_segments`).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Unfinished {
    /// Removed: empty for `UNFINISHED_AGE` (1 s) or longer.
    pub removed: u64,
    /// Left for a later round: younger, perhaps being made.
    pub young: u64,
}

/// How long a shared memory segment may stay empty before it counts as abandoned: iceoryx2 sizes
/// a segment within microseconds of making it.
const UNFINISHED_AGE: Duration = Duration::from_secs(1);

/// Removes the empty shared memory segments (`/dev/shm`) of the prefix that have been empty for
/// [`UNFINISHED_AGE`]: a process killed between creating a segment and giving it its size leaves
/// it so, and iceoryx2 0.10, opening it (to clean up the dead process, to list or open a
/// service), waits for it to get a size without end. In the housekeeper that wait would stop
/// cleanup and camera discovery for good and keep the daemon from stopping (it joins the
/// thread); so a round with younger empty segments left leaves iceoryx2's cleanup and the
/// camera listing to the next round, when those are either sized or old enough to go. Only
/// root meets such segments: made with mode 0200, they are refused to other users, and
/// iceoryx2 then removes them itself.
fn remove_unfinished_segments(segments: &mut Vec<Segment>) -> Unfinished {
    let mut unfinished = Unfinished::default();
    segments.retain(|segment| {
        let empty = segment
            .metadata
            .as_ref()
            .is_ok_and(|m| m.is_file() && m.len() == 0);
        if !empty {
            return true;
        }
        if !older_than(&segment.metadata, UNFINISHED_AGE) {
            unfinished.young += 1;
            return true;
        }
        if std::fs::remove_file(&segment.path).is_err() {
            return true;
        }
        tracing::info!(
            segment = segment.name,
            "removed an empty segment of a dead process"
        );
        unfinished.removed += 1;
        false
    });
    unfinished
}

/// Removes the listeners' files of the prefix that no node's port tag (`<prefix><port id>.port_tag`
/// in its folder) accounts for, older than [`ORPHAN_AGE`]: a listener's socket
/// (`<prefix><port id>.event` in iceoryx2's root folder) and its segment
/// (`<prefix><hash>_<port id>.event_mgmt` in `/dev/shm`). A listener's port tag is made before
/// them and removed after them. iceoryx2's cleanup of a dead node removes the listeners its
/// services list, then the node's port tags; a client killed after it made its reply
/// listener's files but before the service listed the listener leaves them behind, about once
/// in a few hundred kills. A client that crashes in a loop for weeks would otherwise fill both
/// folders. The tags found are remembered in `tagged`. Returns how many listeners' files went.
fn remove_orphan_listeners(
    config: &iceoryx2::config::Config,
    segments: &[Segment],
    tagged: &mut std::collections::HashMap<u128, std::path::PathBuf>,
) -> u64 {
    use std::collections::HashMap;
    use std::path::PathBuf;
    let prefix = config.global.prefix.to_string();
    let sockets: Vec<(u128, PathBuf, bool)> =
        std::fs::read_dir(config.global.root_path().to_string())
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let id = name
                    .strip_prefix(&prefix)?
                    .strip_suffix(".event")?
                    .parse()
                    .ok()?;
                Some((id, e.path(), older_than(&e.metadata(), ORPHAN_AGE)))
            })
            .collect();
    let listener_segments = segments.iter().filter_map(|segment| {
        let (_, id) = segment.name.strip_suffix(".event_mgmt")?.rsplit_once('_')?;
        let id = id.parse().ok()?;
        Some((
            id,
            segment.path.clone(),
            older_than(&segment.metadata, ORPHAN_AGE),
        ))
    });
    // Each listener's files by port id, and whether all of them are old.
    let mut found: HashMap<u128, (Vec<PathBuf>, bool)> = HashMap::new();
    for (id, path, is_old) in sockets.into_iter().chain(listener_segments) {
        let entry = found.entry(id).or_insert((Vec::new(), true));
        entry.0.push(path);
        entry.1 &= is_old;
    }
    let mut old: HashMap<u128, Vec<PathBuf>> = found
        .into_iter()
        .filter(|(_, (_, is_old))| *is_old)
        .map(|(id, (paths, _))| (id, paths))
        .collect();
    // A live listener's files have its tag; those of a listener being made are young.
    tagged.retain(|id, tag| old.contains_key(id) && tag.exists());
    old.retain(|id, _| !tagged.contains_key(id));
    if old.is_empty() {
        return 0;
    }
    let nodes = PathBuf::from(config.global.node_dir().to_string());
    let folders: Vec<PathBuf> = std::fs::read_dir(&nodes)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .bytes()
                .all(|b| b.is_ascii_digit())
        })
        .map(|e| e.path())
        .collect();
    let mut removed = 0;
    for (id, paths) in old {
        let name = format!("{prefix}{id}.port_tag");
        if let Some(tag) = folders.iter().map(|f| f.join(&name)).find(|t| t.exists()) {
            tagged.insert(id, tag);
            continue;
        }
        let gone = paths
            .iter()
            .filter(|path| std::fs::remove_file(path).is_ok())
            .count();
        removed += u64::from(gone > 0);
    }
    removed
}

/// Removes the entries a dead node `id` left under `config`'s node directory: its monitor files
/// (`<prefix><id>.node_monitor…`) and, in its folder `<id>/`, the files of the prefix (and the
/// folder once empty). Returns how many entries went.
fn remove_node_leftovers(config: &iceoryx2::config::Config, id: u128) -> usize {
    let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
    let prefix = config.global.prefix.to_string();
    let monitor = format!("{prefix}{id}.");
    let mut removed = 0;
    if let Ok(entries) = std::fs::read_dir(&nodes) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&monitor)
                && std::fs::remove_file(e.path()).is_ok()
            {
                removed += 1;
            }
        }
    }
    let folder = nodes.join(id.to_string());
    removed += services::remove_node_entries(&folder, &prefix);
    // The node is dead: its folder goes even when nothing of it was left to remove.
    if std::fs::remove_dir(&folder).is_ok() {
        removed += 1;
    }
    removed
}

/// What the I/O thread asks of the housekeeper.
enum Ask {
    /// Look for cameras now (one announced itself).
    Scan,
    /// The I/O thread let go of this camera (or did not subscribe): report it again at the next
    /// scan that finds it.
    Forget(String),
}

/// The housekeeping thread. Dropping it stops and joins the thread.
pub struct Housekeeper {
    ask: Option<Sender<Ask>>,
    found: Receiver<Vec<String>>,
    thread: Option<JoinHandle<()>>,
}

/// The camera names among the publish-subscribe services visible with `config`.
fn list_cameras(config: &iceoryx2::config::Config) -> Vec<String> {
    let mut found = Vec::new();
    let listed = Ipc::list(config, |details| {
        if matches!(
            details.static_details.messaging_pattern(),
            MessagingPattern::PublishSubscribe(_)
        ) {
            if let Some(camera) =
                services::camera_of_service(details.static_details.name().as_str())
            {
                found.push(camera.to_owned());
            }
        }
        CallbackProgression::Continue
    });
    if let Err(e) = listed {
        tracing::warn!(error = ?e, "listing services failed");
    }
    found
}

impl Housekeeper {
    /// Starts the thread with its own node on `config`; every `period` it removes what dead
    /// processes left and lists the cameras, then signals `wake`. `thread_setup` runs first on
    /// the new thread (the daemon blocks termination signals there, so they reach the I/O
    /// thread).
    pub fn start(
        config: &iceoryx2::config::Config,
        period: Duration,
        wake: Signaller,
        thread_setup: fn(),
    ) -> Result<Housekeeper> {
        let (ask_tx, ask_rx) = channel();
        let (found_tx, found_rx) = channel();
        let (ready_tx, ready_rx) = sync_channel(1);
        let config = config.clone();
        let thread = std::thread::Builder::new()
            .name("ppfd-housekeeper".into())
            .spawn(move || {
                thread_setup();
                let node = NodeName::new("ppfd-housekeeper")
                    .map_err(resource("node name"))
                    .and_then(|name| {
                        NodeBuilder::new()
                            .name(&name)
                            .config(&config)
                            .create::<Ipc>()
                            .map_err(resource("cannot create the housekeeping node"))
                    });
                let node = match node {
                    Ok(node) => {
                        let _ = ready_tx.send(Ok(()));
                        node
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                serve(&node, period, &ask_rx, &found_tx, wake);
            })
            .map_err(Error::HousekeeperThread)?;
        // A first camera scan at once: cameras that were publishing before the daemon started.
        let _ = ask_tx.send(Ask::Scan);
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Housekeeper {
                ask: Some(ask_tx),
                found: found_rx,
                thread: Some(thread),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => {
                let _ = thread.join();
                Err(Error::HousekeeperDied)
            }
        }
    }

    /// Asks for a camera scan now rather than at the next period.
    pub fn scan_now(&self) {
        if let Some(ask) = &self.ask {
            let _ = ask.send(Ask::Scan);
        }
    }

    /// Report `name` again the next time it is found (the I/O thread forgot the camera, or did
    /// not subscribe to it). A name whose service is gone at a scan is reported again anyway.
    pub fn forget(&self, name: String) {
        if let Some(ask) = &self.ask {
            let _ = ask.send(Ask::Forget(name));
        }
    }

    /// The camera names found since the last call; each name is reported once while its
    /// service exists (and again after [`Housekeeper::forget`]).
    pub fn cameras_found(&self) -> Vec<String> {
        let mut names = Vec::new();
        while let Ok(batch) = self.found.try_recv() {
            names.extend(batch);
        }
        names
    }
}

/// The thread's loop: until the I/O thread's side of `ask` is dropped.
fn serve(
    node: &Node<Ipc>,
    period: Duration,
    ask: &Receiver<Ask>,
    found: &Sender<Vec<String>>,
    wake: Signaller,
) {
    // Dead processes were cleaned up as the daemon started; the first period only looks for
    // cameras (see `start`), and cleanup follows a period later.
    let mut next = Instant::now() + period;
    let mut reported = std::collections::HashSet::new();
    let mut dead = DeadNodes::default();
    loop {
        let scan_only = match ask.recv_timeout(next.saturating_duration_since(Instant::now())) {
            Ok(Ask::Scan) => true,
            Ok(Ask::Forget(name)) => {
                reported.remove(&name);
                continue;
            }
            Err(RecvTimeoutError::Timeout) => false,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        let started = Instant::now();
        if !scan_only {
            next = started + period;
        }
        // A round that panics (a bug, or iceoryx2 meeting files it does not expect) is logged
        // and the next one runs as usual: a thread that ended would stop camera discovery and
        // cleanup for as long as the daemon runs, unseen.
        let round = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            #[cfg(test)]
            if tests::take_panic(&node.config().global.prefix.to_string()) {
                panic!("a round made to panic by a test");
            }
            let unfinished = if scan_only {
                remove_unfinished_segments(&mut segments_of(node.config()))
            } else {
                let sweep = dead.sweep(node.config());
                sweep.log("removed resources of dead processes");
                sweep.unfinished
            };
            // Listing the services opens them, which would wait on an empty segment.
            if unfinished.young > 0 {
                Vec::new()
            } else {
                list_cameras(node.config())
            }
        }));
        let mut cameras = match round {
            Ok(cameras) => cameras,
            Err(_) => {
                tracing::error!("a housekeeping round panicked; the next one runs as usual");
                continue;
            }
        };
        // A name whose service is gone is reported again when it comes back.
        reported.retain(|name| cameras.contains(name));
        cameras.retain(|name| reported.insert(name.clone()));
        tracing::trace!(
            us = started.elapsed().as_micros() as u64,
            cameras = cameras.len(),
            "housekeeping"
        );
        if !cameras.is_empty() {
            if found.send(cameras).is_err() {
                return;
            }
            wake.signal();
        }
    }
}

impl Drop for Housekeeper {
    fn drop(&mut self) {
        drop(self.ask.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wakeup::Wakeup;

    /// The prefix whose housekeeper's next round panics (tests run side by side, each with a
    /// prefix of its own).
    static PANIC_PREFIX: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

    /// Whether the round of `prefix`'s housekeeper is to panic; once.
    pub(super) fn take_panic(prefix: &str) -> bool {
        let mut asked = PANIC_PREFIX.lock().unwrap_or_else(|p| p.into_inner());
        let take = asked.as_deref() == Some(prefix);
        if take {
            *asked = None;
        }
        take
    }

    /// A node of this test process under `config`.
    fn test_node(config: &iceoryx2::config::Config) -> Node<Ipc> {
        NodeBuilder::new()
            .config(config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .unwrap()
    }

    fn config(prefix: &str) -> iceoryx2::config::Config {
        let mut config = iceoryx2::config::Config::default();
        config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
        config
    }

    /// Monitor files of a node that iceoryx2 does not list (a process killed while it made its
    /// node leaves such) are removed once old enough, and only then; the files of a live node
    /// stay. Left alone, nothing would remove them, and their nodes would be reported "removed"
    /// every round.
    #[test]
    fn orphaned_node_files_are_removed_once_and_live_nodes_kept() {
        let prefix = format!("ppfdhk_{}_", std::process::id());
        let config = config(&prefix);
        let live = test_node(&config);
        let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
        let ours = || -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(&nodes)
                .unwrap()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(&prefix))
                .collect();
            v.sort();
            v
        };
        let live_files = ours();
        assert!(!live_files.is_empty(), "the live node has monitor files");
        // A killed process's partial monitor: two of the three files, one old, one fresh.
        let write = |id: u128, age: Duration| {
            for kind in ["node_monitor_context", "node_monitor_owner_lock"] {
                let f = nodes.join(format!("{prefix}{id}.{kind}"));
                let file = std::fs::File::create(&f).unwrap();
                file.set_modified(std::time::SystemTime::now() - age)
                    .unwrap();
            }
        };
        write(111, Duration::from_secs(60));
        write(222, Duration::ZERO);
        // A process killed earlier leaves only its details file in its folder: one old, one
        // fresh.
        let details = |id: u128, age: Duration| {
            let folder = nodes.join(id.to_string());
            std::fs::create_dir_all(&folder).unwrap();
            let file = std::fs::File::create(folder.join(format!("{prefix}node.details"))).unwrap();
            file.set_modified(std::time::SystemTime::now() - age)
                .unwrap();
            folder
        };
        let old_folder = details(333, Duration::from_secs(60));
        let fresh_folder = details(444, Duration::ZERO);
        // Another prefix's node: left, and not read again while it exists.
        let other_folder = nodes.join(format!("{}", 555_u128 + u128::from(std::process::id())));
        std::fs::create_dir_all(&other_folder).unwrap();
        std::fs::File::create(other_folder.join(format!("other{prefix}node.details")))
            .unwrap()
            .set_modified(std::time::SystemTime::now() - Duration::from_secs(60))
            .unwrap();
        // The live node's own details, aged as well: listed, it keeps its folder.
        let live_folder = nodes.join(live.id().value().to_string());
        std::fs::File::options()
            .write(true)
            .open(live_folder.join(format!("{prefix}node.details")))
            .unwrap()
            .set_modified(std::time::SystemTime::now() - Duration::from_secs(60))
            .unwrap();
        let mut dead = DeadNodes::default();
        let sweep = dead.sweep(&config);
        assert_eq!(sweep.leftovers, 2, "{sweep:?}");
        assert!(!old_folder.exists(), "the old details-only folder stays");
        assert!(fresh_folder.exists(), "a node being made lost its folder");
        assert!(
            other_folder.exists(),
            "another prefix's node lost its folder"
        );
        assert!(dead
            .foreign
            .contains(&(555_u128 + u128::from(std::process::id()))));
        assert!(
            live_folder.join(format!("{prefix}node.details")).exists(),
            "the live node lost its details"
        );
        let left = ours();
        // By the whole name: a live node's random id may end in the same digits.
        let of = |id: u32| format!("{prefix}{id}.");
        assert!(!left.iter().any(|n| n.starts_with(&of(111))), "{left:?}");
        assert_eq!(left.iter().filter(|n| n.starts_with(&of(222))).count(), 2);
        assert!(live_files.iter().all(|f| left.contains(f)), "{left:?}");
        // Nothing more to remove: the next round reports nothing.
        assert_eq!(dead.sweep(&config).leftovers, 0);
        let _ = remove_node_leftovers(&config, 222);
        let _ = remove_node_leftovers(&config, 444);
        std::fs::remove_dir_all(&other_folder).unwrap();
        drop(live);
        services::remove_prefix_leftovers(&prefix).unwrap();
    }

    /// A listener socket that no port tag accounts for, old enough, goes with its segment in
    /// `/dev/shm`; one with a tag, a fresh one and another prefix's stay. The names are
    /// iceoryx2's: a real listener's socket, tag and segment carry its port id.
    #[test]
    fn orphaned_listener_sockets_are_removed_and_others_kept() {
        let prefix = format!("ppfdls_{}_", std::process::id());
        let config = config(&prefix);
        let node = test_node(&config);
        let event = services::responses_builder(&node).open_or_create().unwrap();
        let listener = event.listener_builder().create().unwrap();
        let root = std::path::PathBuf::from(config.global.root_path().to_string());
        let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
        let shm = std::path::PathBuf::from(services::SHARED_MEMORY_DIR);
        let names = |dir: &std::path::Path| -> Vec<String> {
            std::fs::read_dir(dir)
                .unwrap()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(&prefix))
                .collect()
        };
        // The real listener's names.
        let sockets = names(&root);
        assert_eq!(sockets.len(), 1, "{sockets:?}");
        let id = sockets[0]
            .strip_prefix(&prefix)
            .and_then(|n| n.strip_suffix(".event"))
            .unwrap()
            .to_owned();
        let node_folder = nodes.join(node.id().value().to_string());
        assert!(names(&node_folder).contains(&format!("{prefix}{id}.port_tag")));
        assert!(names(&shm)
            .iter()
            .any(|n| n.ends_with(&format!("_{id}.event_mgmt"))));

        let aged = |path: std::path::PathBuf, age: Duration| {
            std::fs::File::create(&path)
                .unwrap()
                .set_modified(std::time::SystemTime::now() - age)
                .unwrap();
            path
        };
        let old = Duration::from_secs(60);
        let hash = "33c1ac61b54bf6edd0a0a8390f0c2fd7cf74d745";
        // An orphan, with its segment.
        let orphan = aged(root.join(format!("{prefix}111.event")), old);
        let segment = aged(shm.join(format!("{prefix}{hash}_111.event_mgmt")), old);
        // A segment without its socket.
        let lone_segment = aged(shm.join(format!("{prefix}{hash}_555.event_mgmt")), old);
        // A socket whose port tag is in a node's folder (a dead node iceoryx2 has yet to clean).
        let tagged_socket = aged(root.join(format!("{prefix}222.event")), old);
        let dead_folder = nodes.join(format!("{}", 777_u128 + u128::from(std::process::id())));
        std::fs::create_dir_all(&dead_folder).unwrap();
        aged(dead_folder.join(format!("{prefix}222.port_tag")), old);
        // A listener being made, and another prefix's orphan.
        let fresh = aged(root.join(format!("{prefix}333.event")), Duration::ZERO);
        let other = aged(root.join(format!("other{prefix}444.event")), old);

        let mut tagged = std::collections::HashMap::new();
        assert_eq!(
            remove_orphan_listeners(&config, &segments_of(&config), &mut tagged),
            2
        );
        assert!(!orphan.exists() && !segment.exists() && !lone_segment.exists());
        assert!(tagged_socket.exists() && fresh.exists() && other.exists());
        assert!(
            root.join(&sockets[0]).exists(),
            "the live listener lost its socket"
        );
        // The tag found is remembered; once it is gone, the socket goes at the next round.
        assert_eq!(tagged.len(), 1, "{tagged:?}");
        assert_eq!(
            remove_orphan_listeners(&config, &segments_of(&config), &mut tagged),
            0
        );
        std::fs::remove_file(dead_folder.join(format!("{prefix}222.port_tag"))).unwrap();
        assert_eq!(
            remove_orphan_listeners(&config, &segments_of(&config), &mut tagged),
            1
        );
        assert!(!tagged_socket.exists());

        for path in [fresh, other] {
            std::fs::remove_file(path).unwrap();
        }
        std::fs::remove_dir_all(&dead_folder).unwrap();
        drop(listener);
        drop(event);
        drop(node);
        services::remove_prefix_leftovers(&prefix).unwrap();
    }

    /// Segments empty for a second go; younger ones are counted and left, as are segments with
    /// a size and another prefix's.
    #[test]
    fn segments_left_empty_are_removed_once_old() {
        let prefix = format!("ppfdes_{}_", std::process::id());
        let config = config(&prefix);
        let shm = std::path::PathBuf::from(services::SHARED_MEMORY_DIR);
        let hash = "b9fc73e5c1f646968758453273c6c65cb372831b";
        let file = |name: String, bytes: &[u8], age: Duration| {
            let path = shm.join(name);
            std::fs::write(&path, bytes).unwrap();
            std::fs::File::options()
                .write(true)
                .open(&path)
                .unwrap()
                .set_modified(std::time::SystemTime::now() - age)
                .unwrap();
            path
        };
        let old = Duration::from_secs(5);
        let connection = file(format!("{prefix}{hash}_1234_77.connection"), b"", old);
        let dynamic = file(format!("{prefix}{hash}_99.dynamic"), b"", old);
        let young = file(format!("{prefix}{hash}_55.data"), b"", Duration::ZERO);
        let sized = file(format!("{prefix}{hash}_1234.data"), b"x", old);
        let other = file(format!("other{prefix}{hash}_1234_77.connection"), b"", old);

        let unfinished = remove_unfinished_segments(&mut segments_of(&config));
        assert_eq!(
            unfinished,
            Unfinished {
                removed: 2,
                young: 1
            }
        );
        assert!(!connection.exists() && !dynamic.exists());
        assert!(young.exists() && sized.exists() && other.exists());
        // The round that meets a young one leaves iceoryx2's cleanup to the next.
        let sweep = DeadNodes::default().sweep(&config);
        assert_eq!(
            sweep.unfinished,
            Unfinished {
                removed: 0,
                young: 1
            }
        );

        for path in [young, sized, other] {
            std::fs::remove_file(path).unwrap();
        }
    }

    /// Waits up to 5 s for the housekeeper to report something.
    fn next_found(h: &Housekeeper, wake: &Wakeup) -> Vec<String> {
        let until = Instant::now() + Duration::from_secs(5);
        while Instant::now() < until {
            let found = h.cameras_found();
            if !found.is_empty() {
                assert!(wake.drain(), "cameras reported without a wake-up");
                return found;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Vec::new()
    }

    /// A round that panics leaves the thread running: the next scan reports a new camera.
    #[test]
    fn a_round_that_panics_is_followed_by_the_next() {
        let prefix = format!("hkp{}_", std::process::id());
        let config = config(&prefix);
        let wake = Wakeup::new().unwrap();
        let h = Housekeeper::start(&config, Duration::from_secs(3600), wake.signaller(), || {})
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
        *PANIC_PREFIX.lock().unwrap() = Some(prefix.clone());
        h.scan_now();
        let until = Instant::now() + Duration::from_secs(5);
        while PANIC_PREFIX.lock().unwrap().is_some() {
            assert!(Instant::now() < until, "no round ran");
            std::thread::sleep(Duration::from_millis(5));
        }
        let node = NodeBuilder::new().config(&config).create::<Ipc>().unwrap();
        let _camera = services::camera_builder(&node, "after")
            .unwrap()
            .create()
            .unwrap();
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["after".to_owned()]);
        drop(h);
        drop((_camera, node));
        services::remove_prefix_leftovers(&prefix).unwrap();
    }

    #[test]
    fn reports_a_camera_once_and_again_once_forgotten_or_gone() {
        let prefix = format!("hk{}_", std::process::id());
        let config = config(&prefix);
        let wake = Wakeup::new().unwrap();
        // A period far beyond the test: every report below comes from the scan at start or a
        // scan asked for.
        let h = Housekeeper::start(&config, Duration::from_secs(3600), wake.signaller(), || {})
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
        assert!(h.cameras_found().is_empty());

        let node = NodeBuilder::new().config(&config).create::<Ipc>().unwrap();
        let camera = |name| {
            services::camera_builder(&node, name)
                .unwrap()
                .create()
                .unwrap()
        };
        let _left = camera("left");
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["left".to_owned()]);

        let _right = camera("right");
        h.scan_now();
        // "left" is not reported again.
        assert_eq!(next_found(&h, &wake), vec!["right".to_owned()]);
        h.scan_now();
        std::thread::sleep(Duration::from_millis(200));
        assert!(h.cameras_found().is_empty());
        // Once forgotten, "left" is reported again while it exists.
        h.forget("left".to_owned());
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["left".to_owned()]);
        // A camera whose service went away is reported again when it is back.
        drop(_right);
        h.scan_now();
        std::thread::sleep(Duration::from_millis(200));
        assert!(h.cameras_found().is_empty());
        let _right = camera("right");
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["right".to_owned()]);
        drop(h); // stops and joins the thread
        drop((_left, _right, node));
        services::remove_prefix_leftovers(&prefix).unwrap();
    }
}
