//! Service names and port limits, in one place. Every participant opens its services through the
//! builders here, so the daemon, cameras and clients agree on each service's settings whoever
//! creates it first (iceoryx2 treats the settings of an `open` as minimum requirements).
//!
//! | service | pattern | payload / header | who |
//! |---|---|---|---|
//! | `ppfd/camera/<name>/depth` | publish/subscribe | `[u16]` / [`FrameHeader`] | camera → daemon |
//! | `ppfd/detect` | request/response | `[u16]` + [`DetectRequestHeader`] → `[PoseHypothesis]` + [`DetectResponseHeader`] | client ↔ daemon |
//! | `ppfd/control` | request/response | [`ControlRequest`] → `[ModelInfo]` + [`ControlResponseHeader`] | client ↔ daemon |
//! | `ppfd/daemon` | event | [`wake`] ids | cameras, clients → daemon |
//! | `ppfd/responses` | event | one listener per client, named [`reply_listener_name`] | daemon → client |
//!
//! Request/response ports cannot wake a sleeping process by themselves: a client notifies
//! `ppfd/daemon` after sending a request, and the daemon notifies the client's own listener on
//! `ppfd/responses` after answering.

use iceoryx2::node::{Node, NodeView};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::{event, publish_subscribe, request_response};

use crate::control::{ControlRequest, ControlResponseHeader, ModelInfo};
use crate::detect::{DetectRequestHeader, DetectResponseHeader, PoseHypothesis};
use crate::frame::FrameHeader;
use crate::{ProtocolError, CAMERA_NAME_BYTES, MAX_HYPOTHESES_PER_OBJECT, MAX_OBJECTS_PER_REQUEST};

/// The iceoryx2 node name of the daemon: a client waiting for an answer looks for a live node
/// of this name to tell a daemon that is working from one that died. Any server of the
/// [`DETECT`] and [`CONTROL`] services must name its node so.
pub const DAEMON_NODE: &str = "ppfd";
/// The detect request/response service.
pub const DETECT: &str = "ppfd/detect";
/// The control request/response service.
pub const CONTROL: &str = "ppfd/control";
/// The event service that wakes the daemon.
pub const DAEMON_WAKE: &str = "ppfd/daemon";
/// The event service on which the daemon wakes clients.
pub const RESPONSES: &str = "ppfd/responses";
/// Camera services are `ppfd/camera/<name>/depth`.
pub const CAMERA_PREFIX: &str = "ppfd/camera/";
/// Suffix of camera service names.
pub const CAMERA_SUFFIX: &str = "/depth";

/// Event ids on [`DAEMON_WAKE`].
pub mod wake {
    use iceoryx2::prelude::EventId;
    /// A client sent a detect or control request.
    pub const REQUEST: EventId = EventId::new(1);
    /// A camera publisher appeared: the daemon subscribes to it.
    pub const CAMERA_APPEARED: EventId = EventId::new(2);
    /// Largest id used.
    pub const MAX: usize = 2;
}

/// Port limits: capacity is a decision. Sized for one daemon, a handful of cameras and up to
/// [`limits::MAX_CLIENTS`] robot processes, with VGA depth frames.
pub mod limits {
    /// Detect clients at once (robot processes).
    pub const MAX_CLIENTS: usize = 32;
    /// Control clients at once: one per detect client and 8 more, one pool for all. Clients
    /// that only send control requests (`ppf stats`, `ppf models`) take no detect place, so
    /// that they connect while the daemon serves its most detect clients; a control-only
    /// client that stays (a monitor) takes one of these places as long as it lives. The
    /// event services' and nodes' limits ([`MAX_NODES`]) hold these 40 and the daemon and its
    /// cameras, so they are those of the detect clients alone.
    pub const MAX_CONTROL_CLIENTS: usize = MAX_CLIENTS + 8;
    /// Daemons serving at once: 1, plus one while a restarted daemon replaces a dead one.
    pub const MAX_SERVERS: usize = 2;
    /// Outstanding detect requests per client (a client that times out may leave one behind).
    pub const MAX_ACTIVE_REQUESTS_PER_CLIENT: usize = 4;
    /// Requests a client may have loaned (being written) at once.
    pub const MAX_LOANED_REQUESTS: usize = 1;
    /// Responses buffered per request before the oldest is discarded (one is sent).
    pub const RESPONSE_BUFFER: usize = 2;
    /// Processes attached to one service.
    pub const MAX_NODES: usize = 2 * MAX_CLIENTS + 8;
    /// Hypotheses one response can carry.
    pub const MAX_RESPONSE_HYPOTHESES: usize =
        super::MAX_OBJECTS_PER_REQUEST * super::MAX_HYPOTHESES_PER_OBJECT as usize;
    /// Models one `ListModels` response can list.
    pub const MAX_LISTED_MODELS: usize = 256;
    /// Publishers per camera: its driver, plus one while a restarted driver replaces a dead one.
    pub const MAX_CAMERA_PUBLISHERS: usize = 2;
    /// Subscribers per camera: the daemon plus a few viewers or recorders.
    pub const MAX_CAMERA_SUBSCRIBERS: usize = 4;
    /// Frames queued per subscriber; on overflow the oldest is replaced (only the newest
    /// matters).
    pub const CAMERA_SUBSCRIBER_BUFFER: usize = 2;
    /// Frames a subscriber may hold at once: the daemon keeps the newest frame and any older one
    /// still being read by a running detection.
    pub const MAX_BORROWED_FRAMES: usize = 6;
    /// Frames a driver may have loaned (being filled) at once.
    pub const MAX_LOANED_FRAMES: usize = 2;
    /// Frames kept for a subscriber that connects late (it gets the newest at once).
    pub const CAMERA_HISTORY: usize = 1;
    /// Depth values of a VGA frame, the size camera ports are preallocated for.
    pub const VGA_PIXELS: usize = 640 * 480;
}

/// The `ppfd/detect` port factory.
pub type DetectService<S> = iceoryx2::service::port_factory::request_response::PortFactory<
    S,
    [u16],
    DetectRequestHeader,
    [PoseHypothesis],
    DetectResponseHeader,
>;
/// The `ppfd/control` port factory.
pub type ControlService<S> = iceoryx2::service::port_factory::request_response::PortFactory<
    S,
    ControlRequest,
    (),
    [ModelInfo],
    ControlResponseHeader,
>;
/// A camera's port factory.
pub type CameraService<S> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, [u16], FrameHeader>;
/// An event port factory.
pub type EventService<S> = iceoryx2::service::port_factory::event::PortFactory<S>;

fn fixed_name(name: &str) -> ServiceName {
    // The constants above are valid service names (tested below).
    ServiceName::new(name).expect("constant service name is valid")
}

/// The `ppfd/detect` builder with its limits.
pub fn detect_builder<S: Service>(
    node: &Node<S>,
) -> request_response::Builder<[u16], DetectRequestHeader, [PoseHypothesis], DetectResponseHeader, S>
{
    node.service_builder(&fixed_name(DETECT))
        .request_response::<[u16], [PoseHypothesis]>()
        .request_user_header::<DetectRequestHeader>()
        .response_user_header::<DetectResponseHeader>()
        .enable_safe_overflow_for_requests(true)
        .enable_safe_overflow_for_responses(true)
        .enable_fire_and_forget_requests(false)
        .max_active_requests_per_client(limits::MAX_ACTIVE_REQUESTS_PER_CLIENT)
        .max_loaned_requests(limits::MAX_LOANED_REQUESTS)
        .max_response_buffer_size(limits::RESPONSE_BUFFER)
        .max_borrowed_responses_per_pending_response(1)
        .max_servers(limits::MAX_SERVERS)
        .max_clients(limits::MAX_CLIENTS)
        .max_nodes(limits::MAX_NODES)
}

/// The `ppfd/control` builder with its limits.
pub fn control_builder<S: Service>(
    node: &Node<S>,
) -> request_response::Builder<ControlRequest, (), [ModelInfo], ControlResponseHeader, S> {
    node.service_builder(&fixed_name(CONTROL))
        .request_response::<ControlRequest, [ModelInfo]>()
        .response_user_header::<ControlResponseHeader>()
        .enable_safe_overflow_for_requests(true)
        .enable_safe_overflow_for_responses(true)
        .enable_fire_and_forget_requests(false)
        .max_active_requests_per_client(2)
        .max_loaned_requests(1)
        .max_response_buffer_size(limits::RESPONSE_BUFFER)
        .max_borrowed_responses_per_pending_response(1)
        .max_servers(limits::MAX_SERVERS)
        .max_clients(limits::MAX_CONTROL_CLIENTS)
        .max_nodes(limits::MAX_NODES)
}

/// The `ppfd/daemon` wake-up event builder.
pub fn daemon_wake_builder<S: Service>(node: &Node<S>) -> event::Builder<S> {
    node.service_builder(&fixed_name(DAEMON_WAKE))
        .event()
        .max_listeners(limits::MAX_SERVERS)
        .max_notifiers(2 * limits::MAX_CLIENTS + 8)
        .max_nodes(limits::MAX_NODES)
        .event_id_max_value(wake::MAX)
}

/// The `ppfd/responses` event builder.
pub fn responses_builder<S: Service>(node: &Node<S>) -> event::Builder<S> {
    node.service_builder(&fixed_name(RESPONSES))
        .event()
        .max_listeners(2 * limits::MAX_CLIENTS)
        .max_notifiers(limits::MAX_SERVERS)
        .max_nodes(limits::MAX_NODES)
        .event_id_max_value(1)
}

/// A camera's publish/subscribe builder with its limits.
pub fn camera_builder<S: Service>(
    node: &Node<S>,
    camera: &str,
) -> Result<publish_subscribe::Builder<[u16], FrameHeader, S>, ProtocolError> {
    let name = camera_service_name(camera)?;
    Ok(node
        .service_builder(&name)
        .publish_subscribe::<[u16]>()
        .user_header::<FrameHeader>()
        .enable_safe_overflow(true)
        .history_size(limits::CAMERA_HISTORY)
        .subscriber_max_buffer_size(limits::CAMERA_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(limits::MAX_BORROWED_FRAMES)
        .max_publishers(limits::MAX_CAMERA_PUBLISHERS)
        .max_subscribers(limits::MAX_CAMERA_SUBSCRIBERS)
        .max_nodes(limits::MAX_CAMERA_PUBLISHERS + limits::MAX_CAMERA_SUBSCRIBERS + 2))
}

/// Camera names: 1 to 31 bytes of ASCII letters, digits, `_` and `-` (they become part of a
/// service name and of a fixed header field).
pub fn check_camera_name(name: &str) -> Result<(), ProtocolError> {
    let reason = if name.is_empty() {
        Some("is empty")
    } else if name.len() >= CAMERA_NAME_BYTES {
        return Err(ProtocolError::NameTooLong {
            field: "camera",
            name: name.to_owned(),
            max_bytes: CAMERA_NAME_BYTES - 1,
        });
    } else if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        Some("may hold only ASCII letters, digits, '_' and '-'")
    } else {
        None
    };
    match reason {
        Some(reason) => Err(ProtocolError::InvalidName {
            field: "camera",
            name: name.to_owned(),
            reason,
        }),
        None => Ok(()),
    }
}

/// The service name of a camera: `ppfd/camera/<name>/depth`.
pub fn camera_service_name(camera: &str) -> Result<ServiceName, ProtocolError> {
    check_camera_name(camera)?;
    let full = format!("{CAMERA_PREFIX}{camera}{CAMERA_SUFFIX}");
    ServiceName::new(&full).map_err(|e| ProtocolError::InvalidName {
        field: "camera",
        name: camera.to_owned(),
        reason: if matches!(
            e,
            iceoryx2::service::service_name::ServiceNameError::ExceedsMaximumLength
        ) {
            "makes the service name too long"
        } else {
            "is not a valid service name"
        },
    })
}

/// The camera name of a camera service name, `None` for any other service.
pub fn camera_of_service(service_name: &str) -> Option<&str> {
    let camera = service_name
        .strip_prefix(CAMERA_PREFIX)?
        .strip_suffix(CAMERA_SUFFIX)?;
    check_camera_name(camera).ok().map(|_| camera)
}

/// The port name of a client's listener on [`RESPONSES`] for a reply token.
pub fn reply_listener_name(reply_token: u64) -> String {
    format!("ppf-reply-{reply_token:016x}")
}

/// Where iceoryx2 keeps its shared memory segments (POSIX shared memory on Linux).
pub const SHARED_MEMORY_DIR: &str = "/dev/shm";

/// Removes the files iceoryx2 leaves behind under `prefix` once every process using it has
/// ended: its global management segment (16 bytes in `/dev/shm`) outlives every node, and a
/// process killed without cleanup leaves its node and service entries. For a prefix of one's
/// own, made for one run (as `ppf demo` does), after its daemon, drivers and clients are gone;
/// never for a prefix that processes still use. Only the prefix's own entries go, not those of
/// a longer prefix that starts with it ([`is_entry_of_prefix`]). Returns how many entries were
/// removed. Refuses a prefix whose daemon is still running ([`ProtocolError::PrefixServed`]):
/// removing its files would cut off its clients and cameras. The caller's own clients and
/// publishers under the prefix are its to have dropped first.
pub fn remove_prefix_leftovers(prefix: &str) -> Result<usize, ProtocolError> {
    check_prefix(prefix)?;
    // The default configuration's folders, which ppfd's processes all use.
    let config = iceoryx2::config::Config::default();
    if daemon_running(prefix, &config) {
        return Err(ProtocolError::PrefixServed {
            prefix: prefix.to_owned(),
        });
    }
    let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
    let folders = [
        std::path::PathBuf::from(SHARED_MEMORY_DIR),
        std::path::PathBuf::from(config.global.service_dir().to_string()),
        nodes.clone(),
        std::path::PathBuf::from(config.global.root_path().to_string()),
    ];
    let mut removed = 0;
    for dir in &folders {
        let Ok(entries) = std::fs::read_dir(dir) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if is_entry_of_prefix(&name, prefix) {
                let p = e.path();
                let gone = if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                };
                removed += usize::from(gone.is_ok());
            } else if *dir == nodes && name.bytes().all(|b| b.is_ascii_digit()) {
                removed += remove_node_entries(&e.path(), prefix);
            }
        }
    }
    Ok(removed)
}

/// Whether a listed node may be the daemon: a live node named [`DAEMON_NODE`], or one that
/// cannot be told from it (a live node whose details cannot be read, a node of another user or
/// in an undefined state). A client judges the daemon gone, and [`remove_prefix_leftovers`] the
/// prefix free, only when no node may be.
pub fn may_be_the_daemon(state: &NodeState<ipc::Service>) -> bool {
    match state {
        NodeState::Alive(view) => view
            .details()
            .as_ref()
            .is_none_or(|d| d.name().as_str() == DAEMON_NODE),
        NodeState::Dead(_) => false,
        NodeState::Inaccessible(_) | NodeState::Undefined(_) => true,
    }
}

/// Whether a daemon may be running under `prefix` ([`may_be_the_daemon`]), or its nodes cannot
/// be listed: when in doubt, the files stay.
fn daemon_running(prefix: &str, config: &iceoryx2::config::Config) -> bool {
    let mut config = config.clone();
    let Ok(name) = FileName::new(prefix.as_bytes()) else {
        return false;
    };
    config.global.prefix = name;
    let mut running = false;
    let listed = Node::<ipc::Service>::list(&config, |state| {
        running = may_be_the_daemon(&state);
        if running {
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    });
    running || listed.is_err()
}

/// Removes the entries of `prefix` in one node's folder, and the folder once they were its
/// last: iceoryx2 names a node's folder by the node's id, and only the files in it carry the
/// prefix. Returns how many entries were removed.
pub fn remove_node_entries(node_dir: &std::path::Path, prefix: &str) -> usize {
    let Ok(entries) = std::fs::read_dir(node_dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        if is_entry_of_prefix(&e.file_name().to_string_lossy(), prefix) {
            removed += usize::from(std::fs::remove_file(e.path()).is_ok());
        }
    }
    // Fails, and leaves it, while another prefix's node still has entries in it. A folder that
    // was empty already is left: it may be a node being made.
    if removed > 0 && std::fs::remove_dir(node_dir).is_ok() {
        removed += 1;
    }
    removed
}

/// Whether a request/response service could not be opened because its messages have another
/// layout, or its ports other limits, than this build's: processes of another protocol version
/// hold it.
pub fn is_other_protocol_version(e: &request_response::RequestResponseOpenOrCreateError) -> bool {
    use request_response::RequestResponseOpenError as Open;
    matches!(
        e,
        request_response::RequestResponseOpenOrCreateError::RequestResponseOpenError(
            Open::IncompatibleRequestOrResponseType
                | Open::DoesNotSupportRequestedAmountOfClients
                | Open::DoesNotSupportRequestedAmountOfServers
                | Open::DoesNotSupportRequestedAmountOfNodes,
        )
    )
}

/// The variable that holds the iceoryx2 prefix when none is given.
pub const PREFIX_VARIABLE: &str = "PPFD_PREFIX";

/// The iceoryx2 prefix from the environment: [`PREFIX_VARIABLE`], if set and not empty. The
/// daemon and its clients both read it, so that one variable brings them together.
pub fn prefix_from_env() -> Option<String> {
    std::env::var(PREFIX_VARIABLE)
        .ok()
        .filter(|p| !p.is_empty())
}

/// `prefix` if given, else [`prefix_from_env`] checked by [`check_prefix`]: a variable's value
/// that would be refused is refused as the variable's ([`ProtocolError::Variable`]). The
/// daemon, its clients and `ppf` all take their prefix through it.
pub fn prefix_or_env(prefix: Option<&str>) -> Result<Option<String>, ProtocolError> {
    prefix_or(prefix, prefix_from_env)
}

/// [`prefix_or_env`] with `from_env` reading the variable.
pub fn prefix_or(
    prefix: Option<&str>,
    from_env: impl FnOnce() -> Option<String>,
) -> Result<Option<String>, ProtocolError> {
    if let Some(prefix) = prefix {
        return Ok(Some(prefix.to_owned()));
    }
    let Some(from_env) = from_env() else {
        return Ok(None);
    };
    check_prefix(&from_env).map_err(|e| ProtocolError::Variable {
        variable: PREFIX_VARIABLE,
        error: Box::new(e),
    })?;
    Ok(Some(from_env))
}

/// The longest prefix taken. iceoryx2 begins every file name it makes with it, and one is the
/// path of a Unix socket, which must fit 108 bytes with its final NUL:
/// `/tmp/iceoryx2/<prefix><listener id>.event`, the id up to 39 decimal digits.
pub const MAX_PREFIX_BYTES: usize = 108 - "/tmp/iceoryx2/".len() - 39 - ".event".len() - 1;

/// Checks an iceoryx2 resource prefix as the daemon and its clients take it (`--prefix`,
/// `PPFD_PREFIX`): a name of ASCII letters, digits, `_` and `-` (it becomes part of file names),
/// at most [`MAX_PREFIX_BYTES`] long, that ends with `_`. iceoryx2 writes ids and hashes right
/// after the prefix; without the separator one prefix can be the start of another's file names
/// (`cell1` of `cell10`'s), and the daemon of one would take the other's live nodes for its own
/// dead ones.
pub fn check_prefix(prefix: &str) -> Result<(), ProtocolError> {
    let reason = if prefix.is_empty() || prefix == "_" {
        "is empty"
    } else if !prefix
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        "may hold only ASCII letters, digits, '_' and '-'"
    } else if prefix.len() > MAX_PREFIX_BYTES {
        "is longer than 48 bytes (iceoryx2 makes socket paths of it)"
    } else if !prefix.ends_with('_') {
        "must end with '_' (\"cell1_\", not \"cell1\"), so that it is not the start of another \
         prefix's file names"
    } else {
        return Ok(());
    };
    Err(ProtocolError::InvalidName {
        field: "prefix",
        name: prefix.to_owned(),
        reason,
    })
}

/// Whether the iceoryx2 file or folder named `name` belongs to `prefix` (checked by
/// [`check_prefix`]), not to a longer prefix that starts with it: after the prefix come a node,
/// port or event id (digits, then `.`), a service's hash (40 hex digits, then `.` or `_`), or
/// `node.` (a node's details). Another prefix's names go on with more of that prefix, which
/// ends with `_`, where an id goes on with `.`.
pub fn is_entry_of_prefix(name: &str, prefix: &str) -> bool {
    let Some(rest) = name.strip_prefix(prefix) else {
        return false;
    };
    let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
    if digits > 0 && rest[digits..].starts_with('.') {
        return true;
    }
    let hex = rest
        .bytes()
        .take_while(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(b))
        .count();
    if hex == 40 && matches!(rest.as_bytes().get(40), Some(b'.' | b'_')) {
        return true;
    }
    rest.starts_with("node.")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A prefix given wins over the variable, unchecked here (its flag checks it); the
    /// variable's value is checked, and a refusal names the variable.
    #[test]
    fn the_variables_prefix_is_checked_and_named() {
        fn set(v: &'static str) -> impl FnOnce() -> Option<String> {
            move || Some(v.to_owned())
        }
        assert_eq!(
            prefix_or(Some("a_"), set("bad")).unwrap().as_deref(),
            Some("a_")
        );
        assert_eq!(
            prefix_or(None, set("cell1_")).unwrap().as_deref(),
            Some("cell1_")
        );
        assert_eq!(prefix_or(None, || None).unwrap(), None);
        let refused = prefix_or(None, set("cell1")).unwrap_err();
        assert!(
            matches!(&refused, ProtocolError::Variable { variable: "PPFD_PREFIX", error }
                if matches!(**error, ProtocolError::InvalidName { field: "prefix", .. })),
            "{refused:?}"
        );
        let text = refused.to_string();
        assert!(
            text.starts_with("PPFD_PREFIX: prefix name \"cell1\" must end with '_'"),
            "{text}"
        );
    }

    #[test]
    fn fixed_names_are_valid_service_names() {
        for n in [DETECT, CONTROL, DAEMON_WAKE, RESPONSES] {
            assert!(ServiceName::new(n).is_ok(), "{n}");
        }
        assert!(PortName::new(&reply_listener_name(u64::MAX)).is_ok());
    }

    #[test]
    fn camera_names_round_trip_through_service_names() {
        let s = camera_service_name("left-kinect_2").unwrap();
        assert_eq!(s.as_str(), "ppfd/camera/left-kinect_2/depth");
        assert_eq!(camera_of_service(s.as_str()), Some("left-kinect_2"));
        assert_eq!(camera_of_service("ppfd/detect"), None);
        assert_eq!(camera_of_service("ppfd/camera/a/b/depth"), None);
    }

    #[test]
    fn a_prefix_ends_with_an_underscore() {
        assert!(check_prefix("cell1_").is_ok());
        assert!(check_prefix("ppfdt_a-b_7_").is_ok());
        assert_eq!(MAX_PREFIX_BYTES, 48);
        assert!(check_prefix(&format!("{}_", "a".repeat(47))).is_ok());
        let long = format!("{}_", "a".repeat(48));
        for (bad, why) in [
            ("cell1", "must end with '_'"),
            ("", "is empty"),
            ("_", "is empty"),
            ("a/b_", "only ASCII"),
            ("caméra_", "only ASCII"),
            (long.as_str(), "longer than 48 bytes"),
        ] {
            let e = check_prefix(bad).unwrap_err().to_string();
            assert!(e.contains(why), "{bad:?}: {e}");
        }
    }

    /// A prefix of the longest length taken makes a node and an event listener (a Unix socket,
    /// the longest path iceoryx2 makes of it).
    #[test]
    fn the_longest_prefix_taken_makes_a_listener() {
        let mut prefix = format!("ppfdlong{}_", std::process::id());
        let fill = MAX_PREFIX_BYTES - prefix.len();
        prefix.insert_str(0, &"p".repeat(fill));
        assert_eq!(prefix.len(), MAX_PREFIX_BYTES);
        check_prefix(&prefix).unwrap();
        let mut config = iceoryx2::config::Config::default();
        config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
        {
            let node = NodeBuilder::new()
                .config(&config)
                .signal_handling_mode(SignalHandlingMode::Disabled)
                .create::<ipc::Service>()
                .unwrap();
            let service = node
                .service_builder(&ServiceName::new("long/prefix").unwrap())
                .event()
                .open_or_create()
                .unwrap();
            let _listener = service.listener_builder().create().unwrap();
        }
        remove_prefix_leftovers(&prefix).unwrap();
    }

    #[test]
    fn a_prefix_owns_its_entries_and_not_those_of_a_longer_prefix() {
        let hash = "9204dd183d1c4d8e1ff592a30766ffa6765aa8b5";
        let own = [
            "158456431172168007222510493951.port_tag".to_owned(),
            "247278885413080472254964.node_monitor_context".to_owned(),
            "316912687947283180432687916654.event".to_owned(),
            "node.details".to_owned(),
            format!("{hash}.service"),
            format!("{hash}.service_tag"),
            format!("{hash}_1584564.dynamic"),
            format!("{hash}_node.0_10_0.global_mgmt"),
            // A node's folder is named by its id alone; it is checked by what it holds.
        ];
        for rest in &own {
            assert!(
                is_entry_of_prefix(&format!("cell_{rest}"), "cell_"),
                "{rest}"
            );
            // Names of the longer prefixes `cell_1_`, `cell_node_` and `cell_ab_`.
            for longer in ["1_", "node_", "ab_"] {
                let name = format!("cell_{longer}{rest}");
                assert!(!is_entry_of_prefix(&name, "cell_"), "{name}");
                assert!(
                    is_entry_of_prefix(&name, &format!("cell_{longer}")),
                    "{name}"
                );
            }
        }
        assert!(!is_entry_of_prefix("other_node.details", "cell_"));
    }

    #[test]
    fn bad_camera_names_are_refused() {
        assert!(check_camera_name("").is_err());
        assert!(check_camera_name("a/b").is_err());
        assert!(check_camera_name("caméra").is_err());
        assert!(check_camera_name(&"x".repeat(CAMERA_NAME_BYTES)).is_err());
        assert!(check_camera_name(&"x".repeat(CAMERA_NAME_BYTES - 1)).is_ok());
    }

    /// A node under a prefix of its own, and the prefix.
    fn isolated_node(tag: &str) -> (Node<ipc::Service>, String) {
        let mut config = iceoryx2::config::Config::default();
        let prefix = format!("ppfdt_{tag}_{}_", std::process::id());
        config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
        let node = NodeBuilder::new()
            .config(&config)
            .create::<ipc::Service>()
            .unwrap();
        (node, prefix)
    }

    #[test]
    fn the_builders_agree_and_carry_an_inline_frame_round_trip() {
        let (node, prefix) = isolated_node("rr");
        round_trip(node);
        // What iceoryx2 leaves of the prefix once everything of it is dropped.
        remove_prefix_leftovers(&prefix).unwrap();
    }

    fn round_trip(node: Node<ipc::Service>) {
        let server_side = detect_builder(&node).create().unwrap();
        // A second participant opens the same service with the same limits.
        let client_side = detect_builder(&node).open().unwrap();
        let server = server_side
            .server_builder()
            .initial_max_slice_len(64)
            .create()
            .unwrap();
        let client = client_side
            .client_builder()
            .initial_max_slice_len(8)
            .create()
            .unwrap();

        let mut request = client.loan_slice_uninit(8).unwrap();
        request.user_header_mut().request_id = 42;
        let request = request.write_from_fn(|i| i as u16);
        let pending = request.send().unwrap();

        let active = server.receive().unwrap().expect("request arrived");
        assert_eq!(active.user_header().request_id, 42);
        assert_eq!(active.payload(), &[0, 1, 2, 3, 4, 5, 6, 7]);
        let mut response = active.loan_slice_uninit(1).unwrap();
        response.user_header_mut().request_id = 42;
        let response = response.write_from_fn(|_| PoseHypothesis {
            object_id: 7,
            ..Default::default()
        });
        response.send().unwrap();

        let answer = pending.receive().unwrap().expect("response arrived");
        assert_eq!(answer.user_header().request_id, 42);
        assert_eq!(answer.payload()[0].object_id, 7);

        let wake = daemon_wake_builder(&node).create().unwrap();
        let _opened = daemon_wake_builder(&node).open().unwrap();
        let camera = camera_builder(&node, "cam0").unwrap().create().unwrap();
        let _opened = camera_builder(&node, "cam0").unwrap().open().unwrap();
        drop((wake, camera));
    }

    #[test]
    fn response_capacity_covers_the_largest_request() {
        assert_eq!(
            limits::MAX_RESPONSE_HYPOTHESES,
            MAX_OBJECTS_PER_REQUEST * MAX_HYPOTHESES_PER_OBJECT as usize
        );
    }
}
