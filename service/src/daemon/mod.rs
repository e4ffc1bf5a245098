//! The I/O thread: owns the iceoryx2 ports, sleeps on a WaitSet, and hands detections to a
//! rayon pool.
//!
//! Life of a detect request: a client sends it on `ppfd/detect` and notifies `ppfd/daemon`; the
//! WaitSet wakes this thread, which takes the request off the port, checks it against the
//! contract and the loaded models (refusing at once what cannot be served) and queues it. When a
//! detection slot is free, the request's frame is resolved — the newest sample of its camera, or
//! its own inline payload — and a job runs on the pool with the request, reading the depth
//! values straight from shared memory. The worker writes the response into a loaned response
//! slice, sends it and wakes the client's listener on `ppfd/responses` (see [`Responder`]); then
//! it reports on a channel and signals an eventfd, and this thread counts the outcome and
//! releases the frame.
//!
//! No depth value is copied on this path: the job gets a pointer into the sample (or request).
//! The request travels with the job and is dropped only after its answer; an `Rc` of the sample
//! sits in the job's `InFlight` record on this thread until the job's completion is received,
//! and the daemon never drops a record before that (see the `Drop` of `Daemon`).
//!
//! The state is one `Daemon`, owned by the I/O thread; its parts by concern:
//!
//! - `queue`: detect requests taken off the port, checked against the contract and the loaded
//!   models, queued, and dispatched in arrival order as detection slots free up;
//! - `job`: a detection started: its frame resolved and checked, and a job on the pool that
//!   reads it in place and answers;
//! - `cameras`: subscriptions to the cameras the housekeeper finds, and forgetting those
//!   without a driver;
//! - `housekeeping`: the I/O thread's share of housekeeping (older frames, dead clients);
//! - `startup`: the models folder, loaded at start on a thread of its own;
//! - `control`: control requests (listing, statistics, loads and drops) and their answers;
//! - `load`: a model loaded or built at run time (`LoadModel`), on a thread of its own;
//! - `shutdown`: the clean stop, and waiting for the running detections.

use std::collections::{HashMap, VecDeque};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

use ppfd_protocol::control::{ControlRequest, ControlResponseHeader, ModelInfo};
use ppfd_protocol::detect::{DetectRequestHeader, DetectResponseHeader, PoseHypothesis};
use ppfd_protocol::frame::FrameHeader;
use ppfd_protocol::services::{self, limits, wake};

use crate::config::DaemonConfig;
use crate::engine::DetectionEngine;
use crate::error::{resource, Error, Result};
use crate::housekeeper::Housekeeper;
use crate::registry::Registry;
use crate::responder::{self, ControlActive, Ipc, Responder};
use crate::stats::Stats;
use crate::termination::{block_termination_signals, TerminationSignals};
use crate::wakeup::{Signaller, Wakeup};

mod cameras;
mod control;
mod housekeeping;
mod job;
mod load;
mod queue;
mod shutdown;
mod startup;

use cameras::Camera;
use job::{Completion, InFlight};
use load::{LoadReport, WaitingLoad};
use queue::Queued;
use startup::StartupLoad;

type DetectServer = Server<Ipc, [u16], DetectRequestHeader, [PoseHypothesis], DetectResponseHeader>;
type ControlServer = Server<Ipc, ControlRequest, (), [ModelInfo], ControlResponseHeader>;
type FrameSample = Sample<Ipc, [u16], FrameHeader>;
type FrameSubscriber = Subscriber<Ipc, [u16], FrameHeader>;

/// The iceoryx2 configuration of a daemon (and of its clients): the default one, with the
/// configured prefix.
fn iceoryx_config(prefix: Option<&str>) -> Result<iceoryx2::config::Config> {
    let mut config = iceoryx2::config::Config::default();
    // The housekeeper cleans up dead processes, after removing the empty segments iceoryx2
    // would wait on without end (`housekeeper::remove_unfinished_segments`); iceoryx2's own
    // cleanup, on a node's creation and end and on opening a service (a camera's, on the I/O
    // thread), would not.
    config.global.node.cleanup_dead_nodes_on_creation = false;
    config.global.node.cleanup_dead_nodes_on_destruction = false;
    config.global.service.cleanup_dead_nodes_on_open = false;
    if let Some(prefix) = prefix {
        config.global.prefix = FileName::new(prefix.as_bytes())
            .map_err(resource(&format!("iceoryx2 prefix {prefix:?}")))?;
    }
    Ok(config)
}

/// The daemon's iceoryx2 node. iceoryx2 reports a folder it cannot write only as
/// "InternalError", so the refusal says where it keeps its files and what to check.
fn create_node(iox: &iceoryx2::config::Config) -> Result<Node<Ipc>> {
    NodeBuilder::new()
        .name(&NodeName::new(services::DAEMON_NODE).map_err(resource("node name"))?)
        .config(iox)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| Error::Resource {
            what: "cannot create the iceoryx2 node".into(),
            detail: format!(
                "{e:?}: iceoryx2 keeps its files in {} and /dev/shm; can this user write both? \
                 (files another user's daemon left there belong to that user: remove them, or \
                 give this daemon a --prefix of its own)",
                iox.global.root_path()
            ),
        })
}

/// The detection workers. A job that panics outside the engine (whose panics its job turns
/// into an internal error) is logged and its worker goes on: rayon's default is to abort the
/// process, which would take every model and running detection with it.
fn worker_pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("ppfd-worker-{i}"))
        .start_handler(|_| block_termination_signals())
        .panic_handler(|payload| {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".to_owned());
            tracing::error!(
                panic = %what,
                "a detection job panicked after its detection; its request is counted abandoned"
            );
        })
        .build()
        .map_err(resource("cannot start the worker pool"))
}

/// How many connections of dead clients the daemon's servers keep while the daemon still holds
/// one of their requests (iceoryx2 panics beyond it). What the daemon holds of dead clients:
/// queued requests (until the next housekeeping round drops them), running detections, and the
/// abandoned requests the responder keeps back (see [`Responder::release_one_abandoned`]).
fn expired_connection_buffer(config: &DaemonConfig) -> usize {
    let held = config.queue_capacity
        + config.parallel_detections
        + responder::MAX_ABANDONED_HELD
        + limits::MAX_CLIENTS;
    held.max(128)
}

/// The daemon's state, owned by the I/O thread. Field order is drop order: what workers may
/// still read goes first, the ports after, the node last.
pub(crate) struct Daemon {
    /// The models folder's loading at start, until it ends.
    startup: Option<StartupLoad>,
    /// The models folder's files at start: all, loaded or failed, failed (as
    /// [`StartupLoad::progress`] gives them). The statistics say how many failed for as long as
    /// the daemon runs, where the log's lines about them may be long gone.
    startup_files: (u64, u64, u64),
    /// Control requests other than statistics that came while the models loaded at start,
    /// handled once they have.
    held_control: Vec<ControlActive>,
    /// Set once a stop is requested: new detect requests, and model loads and drops, are
    /// refused "shutting down" while the running detections finish.
    shutting_down: bool,
    in_flight: HashMap<u64, InFlight>,
    queue: VecDeque<Queued>,
    control_pending: HashMap<u64, ControlActive>,
    /// Model loads waiting for their turn, those whose files are being checked (by job), and
    /// the job of the one running (one at a time).
    waiting_loads: VecDeque<WaitingLoad>,
    checking_loads: HashMap<u64, WaitingLoad>,
    loading: Option<u64>,
    cameras: HashMap<String, Camera>,
    detect_server: DetectServer,
    control_server: ControlServer,
    responder: Arc<Responder>,
    _responses_service: services::EventService<Ipc>,
    registry: Registry,
    engine: Arc<dyn DetectionEngine>,
    pool: rayon::ThreadPool,
    done_tx: Sender<Completion>,
    done_rx: Receiver<Completion>,
    loaded_tx: Sender<LoadReport>,
    loaded_rx: Receiver<LoadReport>,
    signaller: Signaller,
    next_job: u64,
    stats: Stats,
    config: DaemonConfig,
    last_housekeeping: Instant,
    housekeeper: Housekeeper,
    node: Node<Ipc>,
}

/// Runs a daemon until SIGINT, SIGTERM or SIGHUP. `on_ready` is called once the models of the
/// models folder are loaded and it serves detections; statistics are answered from the start.
/// A stop requested while the models load ends it after the model being loaded, without
/// serving.
///
/// Call it before the process starts other threads, or block the termination signals in them
/// ([`crate::termination::block_termination_signals`]): the daemon reads them from a
/// `signalfd`, which gets a signal only when every thread blocks it (otherwise the kernel
/// hands it to a thread that does not).
pub fn run(
    config: DaemonConfig,
    engine: Arc<dyn DetectionEngine>,
    on_ready: impl FnOnce(&ReadyInfo),
) -> Result<()> {
    config.validate()?;
    // Before any thread starts: every thread the daemon starts inherits the blocked signals.
    let termination = TerminationSignals::new().map_err(resource(
        "cannot open a signalfd for the termination signals",
    ))?;
    let mut iox = iceoryx_config(config.prefix.as_deref())?;
    iox.defaults
        .request_response
        .server_expired_connection_buffer = expired_connection_buffer(&config);
    let node = create_node(&iox)?;
    crate::housekeeper::DeadNodes::default()
        .sweep(node.config())
        .log("removed resources of crashed processes");

    let wake_service = services::daemon_wake_builder(&node)
        .open_or_create()
        .map_err(resource("cannot open the ppfd/daemon event service"))?;
    // Two daemons listen at most (one replacing a dead one): a third started at the same time
    // as another is refused here, before the server check would name the other daemon.
    let wake_listener = wake_service
        .listener_builder()
        .create()
        .map_err(|e| match e {
            iceoryx2::port::listener::ListenerCreateError::ExceedsMaxSupportedListeners => {
                Error::DaemonsStarting {
                    listeners: limits::MAX_SERVERS,
                }
            }
            e => resource("cannot listen on ppfd/daemon")(e),
        })?;
    let wakeup = Wakeup::new().map_err(resource("cannot create an eventfd"))?;

    let mut daemon = Daemon::new(config, engine, node, wakeup.signaller())?;
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(resource("cannot create the WaitSet"))?;
    let _wake_guard = waitset
        .attach_notification(&wake_listener)
        .map_err(resource("WaitSet"))?;
    let _done_guard = waitset
        .attach_notification(&wakeup)
        .map_err(resource("WaitSet"))?;
    let _termination_guard = waitset
        .attach_notification(&termination)
        .map_err(resource("WaitSet"))?;
    let _tick_guard = waitset
        .attach_interval(Duration::from_millis(daemon.config.housekeeping_ms))
        .map_err(resource("WaitSet"))?;

    daemon.housekeeping();
    if daemon.startup.is_some() {
        tracing::info!("loading models; statistics are answered meanwhile");
    }
    let mut on_ready = Some(on_ready);
    let mut ready_when_loaded = |daemon: &Daemon| {
        if daemon.startup.is_none() {
            if let Some(on_ready) = on_ready.take() {
                on_ready(&ReadyInfo {
                    models: daemon.registry.len(),
                    failed: daemon.startup_files.2,
                    pid: std::process::id(),
                });
                tracing::info!(
                    models = daemon.registry.len(),
                    engine = daemon.engine.name(),
                    "serving"
                );
            }
        }
    };
    daemon.poll_startup();
    ready_when_loaded(&daemon);

    loop {
        let outcome = waitset.wait_and_process_once(|_| CallbackProgression::Continue);
        if let Err(e) = outcome {
            return Err(resource("WaitSet failed")(e));
        }
        // Whatever woke the wait (another signal only interrupts it), the termination signals wait
        // in the signalfd until read here.
        if termination.requested() {
            break;
        }
        let mut events = Vec::new();
        if let Err(e) = wake_listener.try_wait(|a| events.push(a.id)) {
            tracing::warn!(error = ?e, "reading ppfd/daemon events failed");
        }
        wakeup.drain();
        daemon.step(&events);
        ready_when_loaded(&daemon);
    }
    if daemon.startup.is_some() {
        tracing::info!("stopped while loading models, before serving");
    } else {
        tracing::info!("shutting down");
    }
    daemon.shutdown();
    Ok(())
}

/// What a daemon reports when it starts serving.
#[derive(Debug, Clone)]
pub struct ReadyInfo {
    /// Models loaded.
    pub models: usize,
    /// Files of the models folder that did not load (the log says why).
    pub failed: u64,
    /// Process id.
    pub pid: u32,
}

/// The error of a request/response service the daemon could not open; one held with the
/// messages of another protocol version says so.
fn open_service(
    service: &'static str,
) -> impl FnOnce(iceoryx2::service::builder::request_response::RequestResponseOpenOrCreateError) -> Error
{
    move |e| {
        if services::is_other_protocol_version(&e) {
            Error::OtherProtocolVersion {
                service,
                version: ppfd_protocol::PROTOCOL_VERSION,
            }
        } else {
            Error::Resource {
                what: format!("cannot open the {service} service"),
                detail: format!("{e:?}"),
            }
        }
    }
}

impl Daemon {
    fn new(
        config: DaemonConfig,
        engine: Arc<dyn DetectionEngine>,
        node: Node<Ipc>,
        signaller: Signaller,
    ) -> Result<Daemon> {
        let detect_service = services::detect_builder(&node)
            .open_or_create()
            .map_err(open_service(services::DETECT))?;
        let detect_server = detect_service
            .server_builder()
            .initial_max_slice_len(limits::MAX_RESPONSE_HYPOTHESES)
            .max_loaned_responses_per_request(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(resource("cannot serve ppfd/detect"))?;
        let servers = detect_service.dynamic_config().number_of_servers();
        if servers > 1 {
            return Err(Error::AlreadyServing {
                servers,
                service: services::DETECT,
            });
        }
        let control_service = services::control_builder(&node)
            .open_or_create()
            .map_err(open_service(services::CONTROL))?;
        let control_server = control_service
            .server_builder()
            .initial_max_slice_len(limits::MAX_LISTED_MODELS)
            .max_loaned_responses_per_request(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(resource("cannot serve ppfd/control"))?;
        let responses_service = services::responses_builder(&node)
            .open_or_create()
            .map_err(resource("cannot open the ppfd/responses event service"))?;
        let responses = responses_service
            .notifier_builder()
            .create()
            .map_err(resource("cannot notify on ppfd/responses"))?;

        let pool = worker_pool(config.worker_threads())?;
        let housekeeper = Housekeeper::start(
            node.config(),
            Duration::from_millis(config.housekeeping_ms),
            signaller,
            block_termination_signals,
        )?;

        // The models folder loads on a thread of its own: statistics are answered meanwhile,
        // and a stop requested then ends the daemon after the model being loaded.
        let startup = match &config.models {
            Some(dir) => {
                let files = Registry::model_files(engine.as_ref(), dir)?;
                Some(StartupLoad::start(
                    engine.clone(),
                    dir.clone(),
                    files,
                    config.model_cache_dir(),
                    signaller,
                )?)
            }
            None => None,
        };

        let (done_tx, done_rx) = channel();
        let (loaded_tx, loaded_rx) = channel();
        if config.parallel_detections > config.worker_threads() {
            tracing::warn!(
                parallel_detections = config.parallel_detections,
                workers = config.worker_threads(),
                "more detections at once than workers: the ones beyond wait for a worker or share one, each running slower (frame age and the stale limit count from each one's start)"
            );
        }
        Ok(Daemon {
            startup,
            startup_files: (0, 0, 0),
            held_control: Vec::new(),
            shutting_down: false,
            in_flight: HashMap::new(),
            queue: VecDeque::new(),
            control_pending: HashMap::new(),
            waiting_loads: VecDeque::new(),
            checking_loads: HashMap::new(),
            loading: None,
            cameras: HashMap::new(),
            detect_server,
            control_server,
            responder: Arc::new(Responder::new(detect_service, control_service, responses)),
            _responses_service: responses_service,
            registry: Registry::default(),
            engine,
            pool,
            done_tx,
            done_rx,
            loaded_tx,
            loaded_rx,
            signaller,
            next_job: 1,
            stats: Stats::default(),
            config,
            last_housekeeping: Instant::now(),
            housekeeper,
            node,
        })
    }

    /// One turn of the loop: everything that can be done now.
    fn step(&mut self, events: &[EventId]) {
        self.poll_startup();
        if events.contains(&wake::CAMERA_APPEARED) {
            self.housekeeper.scan_now();
        }
        self.open_found_cameras();
        while let Ok(c) = self.done_rx.try_recv() {
            self.finish(c);
        }
        while let Ok(report) = self.loaded_rx.try_recv() {
            self.load_report(report);
        }
        self.take_control_requests();
        self.take_detect_requests();
        if self.last_housekeeping.elapsed() >= Duration::from_millis(self.config.housekeeping_ms) {
            // Before dispatching: it drops dead clients' queued requests and may take new ones.
            self.housekeeping();
        }
        self.dispatch();
        if self.responder.abandoned_held() > responder::MAX_ABANDONED_HELD {
            // Clients died faster than housekeeping comes round.
            self.release_abandoned();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A job that panics after its detection still reports (so its frame is released and a
    /// stop does not wait for it), and the process and the worker live on.
    #[test]
    fn a_job_that_panics_reports_and_its_worker_goes_on() {
        let wakeup = Wakeup::new().unwrap();
        let signaller = wakeup.signaller();
        let pool = worker_pool(1).unwrap();
        let (done, finished) = channel();
        let report = job::Report {
            job: 7,
            outcome: responder::Outcome::Refused,
            done: done.clone(),
            signaller,
        };
        pool.spawn(move || {
            let _report = report;
            panic!("a job made to panic by a test");
        });
        let c = finished.recv_timeout(Duration::from_secs(10)).unwrap();
        assert_eq!((c.job, c.outcome), (7, responder::Outcome::Refused));
        // The signal follows the completion.
        let woken = Instant::now();
        while !wakeup.drain() {
            assert!(
                woken.elapsed() < Duration::from_secs(10),
                "the I/O thread is not woken"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        // The same single worker takes the next job.
        let (tx, rx) = channel();
        pool.spawn(move || {
            tx.send(std::thread::current().name().map(str::to_owned))
                .unwrap()
        });
        let name = rx.recv_timeout(Duration::from_secs(10)).unwrap();
        assert_eq!(name.as_deref(), Some("ppfd-worker-0"));
    }

    /// A folder iceoryx2 cannot write is named, with what to check, not left as "InternalError".
    #[test]
    fn a_node_that_cannot_be_created_says_where_iceoryx2_keeps_its_files() {
        // Below a regular file: no user, root included, can make a folder there.
        let file = std::env::temp_dir().join(format!("ppfd-node-root-{}", std::process::id()));
        std::fs::write(&file, "a file").unwrap();
        let root = file.join("iceoryx2");
        let mut iox = iceoryx_config(Some("ppfdnoderoot")).unwrap();
        let root_text = format!("{}/", root.display());
        iox.global
            .set_root_path(&iceoryx2::prelude::Path::new(root_text.as_bytes()).unwrap());
        let e = create_node(&iox).map(|_| ()).unwrap_err().to_string();
        std::fs::remove_file(&file).unwrap();
        assert!(
            e.contains(&root.display().to_string())
                && e.contains("/dev/shm")
                && e.contains("can this user write"),
            "{e}"
        );
    }
}
