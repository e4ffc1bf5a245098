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
//! sits in the job's [`InFlight`] record on this thread until the job's completion is received,
//! and the daemon never drops a record before that (see [`Daemon`]'s `Drop`).

use std::collections::{HashMap, VecDeque};
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniqueClientId;
use iceoryx2::node::Node;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

use ppfd_protocol::clock::{instant_of, monotonic_now_ns};
use ppfd_protocol::control::{ControlCommand, ControlRequest, ControlResponseHeader, ModelInfo};
use ppfd_protocol::detect::{
    DetectRequestHeader, DetectResponseHeader, FrameSource, PoseHypothesis, Status,
};
use ppfd_protocol::frame::FrameHeader;
use ppfd_protocol::services::{self, limits, wake, CameraService};
use ppfd_protocol::text;

use crate::config::DaemonConfig;
use crate::engine::{DetectOptions, DetectionEngine, EngineError, FrameView, LoadedModel};
use crate::housekeeper::Housekeeper;
use crate::registry::Registry;
use crate::responder::{
    self, ControlActive, DetectActive, Ipc, Outcome, Port, Release, Responder, Served,
};
use crate::stats::Stats;
use crate::termination::{block_termination_signals, TerminationSignals};
use crate::wakeup::{Signaller, Wakeup};

type DetectServer = Server<Ipc, [u16], DetectRequestHeader, [PoseHypothesis], DetectResponseHeader>;
type ControlServer = Server<Ipc, ControlRequest, (), [ModelInfo], ControlResponseHeader>;
type FrameSample = Sample<Ipc, [u16], FrameHeader>;
type FrameSubscriber = Subscriber<Ipc, [u16], FrameHeader>;

/// Why the daemon could not start or had to stop.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct DaemonError(pub String);

fn fail<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> DaemonError + '_ {
    move |e| DaemonError(format!("{what}: {e:?}"))
}

/// The iceoryx2 configuration of a daemon (and of its clients): the default one, with the
/// configured prefix.
pub fn iceoryx_config(prefix: Option<&str>) -> Result<iceoryx2::config::Config, DaemonError> {
    let mut config = iceoryx2::config::Config::default();
    if let Some(prefix) = prefix {
        config.global.prefix = FileName::new(prefix.as_bytes())
            .map_err(|e| DaemonError(format!("iceoryx2 prefix {prefix:?}: {e:?}")))?;
    }
    Ok(config)
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

/// Depth values in shared memory that a worker reads. Valid while the sample (held by the I/O
/// thread) or the request (held by the job itself) they belong to lives (see the module
/// documentation).
struct SharedDepth {
    ptr: *const u16,
    len: usize,
}

// SAFETY: the memory is shared memory that nobody writes while the sample/request is held
// (a published sample and a sent request are immutable), and the holder outlives the job.
unsafe impl Send for SharedDepth {}

impl SharedDepth {
    /// # Safety
    /// The sample or request the values belong to must be alive and unchanged.
    unsafe fn values(&self) -> &[u16] {
        // SAFETY: by the caller's promise the pointer and length describe live memory.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
}

/// A request waiting for a detection slot.
struct Queued {
    active: DetectActive,
    header: DetectRequestHeader,
    source: FrameSource,
    models: Vec<Arc<LoadedModel>>,
    received_ns: u64,
}

/// A request whose detection runs (its worker holds the request and answers it). The frame is
/// released only with the record, after the job reported.
struct InFlight {
    _frame: Option<Rc<FrameSample>>,
    /// The client that sent the request, to tell whether it is still there.
    client: UniqueClientId,
    /// Set to stop the detection early: its client is gone.
    cancel: Arc<AtomicBool>,
}

/// A job's report, sent after its worker answered the request.
struct Completion {
    job: u64,
    outcome: Outcome,
}

struct ModelLoaded {
    job: u64,
    result: Result<LoadedModel, EngineError>,
}

/// A camera the daemon subscribes to, and its newest frame.
struct Camera {
    newest: Option<Rc<FrameSample>>,
    subscriber: FrameSubscriber,
    service: CameraService<Ipc>,
    /// Since when no driver publishes on it (counted at housekeeping rounds).
    driverless_since: Option<Instant>,
}

impl Camera {
    /// Whether the camera has been without a driver for `limit`, as of `now`; keeps count.
    fn driverless_for(&mut self, limit: Duration, now: Instant) -> bool {
        if self.service.dynamic_config().number_of_publishers() > 0 {
            self.driverless_since = None;
            return false;
        }
        let since = *self.driverless_since.get_or_insert(now);
        now.saturating_duration_since(since) >= limit
    }

    /// Takes every waiting frame, keeping the newest. Returns how many arrived.
    fn refresh(&mut self, name: &str) -> u64 {
        let mut n = 0;
        loop {
            match self.subscriber.receive() {
                Ok(Some(sample)) => {
                    n += 1;
                    self.newest = Some(Rc::new(sample));
                }
                Ok(None) => break,
                Err(e) => {
                    // Typically every borrowable frame is held by running detections: the
                    // newest one held stays in use until they finish.
                    tracing::debug!(camera = name, error = ?e, "frame not taken");
                    break;
                }
            }
        }
        n
    }
}

/// The models folder loading at start on a thread of its own, one model after the other; the
/// I/O thread takes each as it comes.
struct StartupLoad {
    dir: PathBuf,
    /// How many model files the folder holds.
    files: usize,
    /// Files done (loaded or failed), and failed.
    done: usize,
    failed: usize,
    started: Instant,
    stop: Arc<AtomicBool>,
    events: Receiver<StartupEvent>,
    thread: Option<std::thread::JoinHandle<()>>,
}

enum StartupEvent {
    Loaded(LoadedModel),
    Failed,
    /// Every file done, or the loading stopped.
    Finished,
}

impl StartupLoad {
    fn start(
        engine: Arc<dyn DetectionEngine>,
        dir: PathBuf,
        files: Vec<PathBuf>,
        cache_dir: PathBuf,
        signaller: Signaller,
    ) -> Result<StartupLoad, DaemonError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, events) = channel();
        let file_count = files.len();
        let thread = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("ppfd-load".into())
                .spawn(move || {
                    block_termination_signals();
                    let send = |event| {
                        let _ = tx.send(event);
                        signaller.signal();
                    };
                    Registry::load_files(
                        engine.as_ref(),
                        &files,
                        Some(&cache_dir),
                        &|| stop.load(Ordering::SeqCst),
                        &mut |model| send(StartupEvent::Loaded(model)),
                        &mut |_, _| send(StartupEvent::Failed),
                    );
                    send(StartupEvent::Finished);
                })
                .map_err(fail("cannot start the model loading thread"))?
        };
        Ok(StartupLoad {
            dir,
            files: file_count,
            done: 0,
            failed: 0,
            started: Instant::now(),
            stop,
            events,
            thread: Some(thread),
        })
    }

    /// Puts the models loaded since the last call into `registry`; whether the loading is over.
    fn take(&mut self, registry: &mut Registry) -> bool {
        // Looked at first: a thread that has ended (even by a panic) has sent all it will.
        let ended = self.thread.as_ref().is_none_or(|t| t.is_finished());
        let mut finished = false;
        while let Ok(event) = self.events.try_recv() {
            match event {
                StartupEvent::Loaded(model) => {
                    self.done += 1;
                    registry.insert(model);
                }
                StartupEvent::Failed => {
                    self.done += 1;
                    self.failed += 1;
                }
                StartupEvent::Finished => finished = true,
            }
        }
        finished || ended
    }

    fn join(&mut self) {
        if let Some(thread) = self.thread.take() {
            if thread.join().is_err() {
                tracing::error!("the model loading thread panicked");
            }
        }
    }

    /// The line statistics carry while the models load: `loading models: 3 of 12 files done
    /// (1 failed), 14 s`.
    fn progress(&self) -> String {
        let failed = if self.failed > 0 {
            format!(" ({} failed)", self.failed)
        } else {
            String::new()
        };
        format!(
            "loading models: {} of {} files done{failed}, {} s",
            self.done,
            self.files,
            self.started.elapsed().as_secs()
        )
    }
}

/// The daemon's state, owned by the I/O thread. Field order is drop order: what workers may
/// still read goes first, the ports after, the node last.
pub struct Daemon {
    /// The models folder's loading at start, until it ends.
    startup: Option<StartupLoad>,
    /// Control requests other than statistics that came while the models loaded at start,
    /// handled once they have.
    held_control: Vec<ControlActive>,
    /// Set once a stop is requested: new detect requests, and model loads and drops, are
    /// refused "shutting down" while the running detections finish.
    shutting_down: bool,
    in_flight: HashMap<u64, InFlight>,
    queue: VecDeque<Queued>,
    control_pending: HashMap<u64, ControlActive>,
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
    loaded_tx: Sender<ModelLoaded>,
    loaded_rx: Receiver<ModelLoaded>,
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
) -> Result<(), DaemonError> {
    config.validate().map_err(DaemonError)?;
    // Before any thread starts: every thread the daemon starts inherits the blocked signals.
    let termination = TerminationSignals::new()
        .map_err(fail("cannot open a signalfd for the termination signals"))?;
    let mut iox = iceoryx_config(config.prefix.as_deref())?;
    iox.defaults
        .request_response
        .server_expired_connection_buffer = expired_connection_buffer(&config);
    let node = NodeBuilder::new()
        .name(&NodeName::new(services::DAEMON_NODE).map_err(fail("node name"))?)
        .config(&iox)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(fail("cannot create the iceoryx2 node"))?;
    let sweep = crate::housekeeper::DeadNodes::default().sweep(node.config());
    if sweep.cleaned + sweep.failed + sweep.leftovers > 0 {
        tracing::info!(
            removed = sweep.cleaned,
            leftovers = sweep.leftovers,
            failed = sweep.failed,
            "removed resources of crashed processes"
        );
    }

    let wake_service = services::daemon_wake_builder(&node)
        .open_or_create()
        .map_err(fail("cannot open the ppfd/daemon event service"))?;
    let wake_listener = wake_service
        .listener_builder()
        .create()
        .map_err(fail("cannot listen on ppfd/daemon"))?;
    let wakeup = Wakeup::new().map_err(fail("cannot create an eventfd"))?;

    let mut daemon = Daemon::new(config, engine, node, wakeup.signaller())?;
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(fail("cannot create the WaitSet"))?;
    let _wake_guard = waitset
        .attach_notification(&wake_listener)
        .map_err(fail("WaitSet"))?;
    let _done_guard = waitset
        .attach_notification(&wakeup)
        .map_err(fail("WaitSet"))?;
    let _termination_guard = waitset
        .attach_notification(&termination)
        .map_err(fail("WaitSet"))?;
    let _tick_guard = waitset
        .attach_interval(Duration::from_millis(daemon.config.housekeeping_ms))
        .map_err(fail("WaitSet"))?;

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
            return Err(DaemonError(format!("WaitSet failed: {e:?}")));
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
    /// Process id.
    pub pid: u32,
}

impl Daemon {
    fn new(
        config: DaemonConfig,
        engine: Arc<dyn DetectionEngine>,
        node: Node<Ipc>,
        signaller: Signaller,
    ) -> Result<Daemon, DaemonError> {
        let detect_service = services::detect_builder(&node)
            .open_or_create()
            .map_err(fail("cannot open the ppfd/detect service"))?;
        let detect_server = detect_service
            .server_builder()
            .initial_max_slice_len(limits::MAX_RESPONSE_HYPOTHESES)
            .max_loaned_responses_per_request(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(fail("cannot serve ppfd/detect"))?;
        let servers = detect_service.dynamic_config().number_of_servers();
        if servers > 1 {
            return Err(DaemonError(format!(
                "another ppfd already serves with this prefix ({servers} servers on {}); stop it first",
                services::DETECT
            )));
        }
        let control_service = services::control_builder(&node)
            .open_or_create()
            .map_err(fail("cannot open the ppfd/control service"))?;
        let control_server = control_service
            .server_builder()
            .initial_max_slice_len(limits::MAX_LISTED_MODELS)
            .max_loaned_responses_per_request(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(fail("cannot serve ppfd/control"))?;
        let responses_service = services::responses_builder(&node)
            .open_or_create()
            .map_err(fail("cannot open the ppfd/responses event service"))?;
        let responses = responses_service
            .notifier_builder()
            .create()
            .map_err(fail("cannot notify on ppfd/responses"))?;

        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(config.worker_threads())
            .thread_name(|i| format!("ppfd-worker-{i}"))
            .start_handler(|_| block_termination_signals())
            .build()
            .map_err(fail("cannot start the worker pool"))?;
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
                let files = Registry::model_files(engine.as_ref(), dir).map_err(DaemonError)?;
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
                "more detections at once than workers: the ones beyond take turns on the workers, each running slower"
            );
        }
        Ok(Daemon {
            startup,
            held_control: Vec::new(),
            shutting_down: false,
            in_flight: HashMap::new(),
            queue: VecDeque::new(),
            control_pending: HashMap::new(),
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

    /// Takes the models loaded at start so far; once the folder is done, logs it, handles the
    /// control requests held meanwhile and lets detections in.
    fn poll_startup(&mut self) {
        let Some(startup) = &mut self.startup else {
            return;
        };
        if !startup.take(&mut self.registry) {
            return;
        }
        let mut startup = self.startup.take().expect("loading");
        startup.join();
        if startup.files == 0 {
            tracing::warn!(
                dir = %startup.dir.display(),
                "no model in the models folder: nothing can be detected until one is loaded (ppf models --load)"
            );
        }
        tracing::info!(
            loaded = self.registry.len(),
            failed = startup.failed,
            bytes = self.registry.bytes(),
            ms = startup.started.elapsed().as_millis() as u64,
            dir = %startup.dir.display(),
            "models loaded"
        );
        for active in std::mem::take(&mut self.held_control) {
            self.control(active);
        }
    }

    /// Ends the loading at start, if it runs, after the model being loaded.
    fn stop_startup(&mut self) {
        if let Some(startup) = self.startup.as_mut() {
            startup.stop.store(true, Ordering::SeqCst);
            startup.join();
            startup.take(&mut self.registry);
        }
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
        while let Ok(m) = self.loaded_rx.try_recv() {
            self.finish_load(m);
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

    /// The I/O thread's share of housekeeping (cleanup and discovery run on the
    /// [`Housekeeper`]'s thread): release older frames, bound the reply-key cache, let go of
    /// dead clients' requests.
    fn housekeeping(&mut self) {
        self.last_housekeeping = Instant::now();
        // Keep only the newest frame of each camera, releasing older ones to their drivers.
        for (name, camera) in &mut self.cameras {
            self.stats.frames_received += camera.refresh(name);
        }
        self.forget_driverless_cameras();
        self.responder.trim();
        self.drop_dead_clients_requests();
        self.cancel_dead_clients_detections();
        self.release_abandoned();
    }

    /// Stops the running detections of clients that died: they would hold a worker for
    /// seconds to compute an answer nobody reads, while the queue waits behind them.
    fn cancel_dead_clients_detections(&mut self) {
        for (job, f) in &self.in_flight {
            if !f.cancel.load(Ordering::Relaxed) && !self.responder.detect_client_listed(f.client) {
                f.cancel.store(true, Ordering::Relaxed);
                tracing::debug!(job, "client gone: its running detection is cancelled");
            }
        }
    }

    /// Lets go of the dead clients' requests that can be let go of (see
    /// [`Responder::release_one_abandoned`]), one at a time.
    fn release_abandoned(&mut self) {
        let mut forced = 0;
        while let Some((port, release)) = self.responder.release_one_abandoned() {
            forced += usize::from(release == Release::Forced);
            // The receive lets iceoryx2 forget the dead client's connection (and takes any
            // request that came in meanwhile).
            match port {
                Port::Detect => self.take_detect_requests(),
                Port::Control => self.take_control_requests(),
            }
        }
        if forced > 0 {
            tracing::warn!(
                released = forced,
                "released requests of dead clients whose channels may serve new clients (more than {} held)",
                responder::MAX_ABANDONED_HELD
            );
        }
        let held = self.responder.abandoned_held();
        if held > 0 {
            tracing::debug!(held, "requests of dead clients not yet released");
        }
    }

    /// Takes the queued requests of clients that died off the queue: while queued, each keeps
    /// the dead client's connection (and its shared memory) alive.
    fn drop_dead_clients_requests(&mut self) {
        if self.queue.is_empty() {
            return;
        }
        let queued = std::mem::take(&mut self.queue);
        for q in queued {
            if self.responder.detect_client_alive(&q.active) {
                self.queue.push_back(q);
            } else {
                let outcome = self.responder.abandon(q.active, q.header.request_id);
                self.count(outcome);
            }
        }
    }

    // ---------------------------------------------------------------- cameras

    /// Subscribes to the cameras the housekeeper found. One that cannot be subscribed to now
    /// (no driver publishes on it yet, or any more) is reported again at the next scan.
    fn open_found_cameras(&mut self) {
        for name in self.housekeeper.cameras_found() {
            if !self.cameras.contains_key(&name) {
                if let Err(e) = self.open_camera(&name) {
                    tracing::debug!(camera = %name, error = %e.message, "camera not opened");
                    self.housekeeper.forget(name);
                }
            }
        }
    }

    /// Lets go of the cameras that have had no driver for `forget_camera_after_ms` (see
    /// [`DaemonConfig::forget_camera_after_ms`]). A detection still running on one of their
    /// frames keeps that frame (iceoryx2's sample holds what it needs of the subscriber); the
    /// last frame and the subscription go, and with them the service once nobody else holds it.
    fn forget_driverless_cameras(&mut self) {
        let limit = Duration::from_millis(self.config.forget_camera_after_ms);
        let now = Instant::now();
        let gone: Vec<String> = self
            .cameras
            .iter_mut()
            .filter_map(|(name, camera)| camera.driverless_for(limit, now).then(|| name.clone()))
            .collect();
        for name in gone {
            self.cameras.remove(&name);
            tracing::info!(
                camera = %name,
                "forgot camera: no driver for {} ms",
                self.config.forget_camera_after_ms
            );
            // Found again once a driver publishes under the name (the service may outlive the
            // subscription a while: a running detection's frame keeps it).
            self.housekeeper.forget(name);
        }
    }

    fn open_camera(&mut self, name: &str) -> Result<&mut Camera, EngineError> {
        if !self.cameras.contains_key(name) {
            let builder = services::camera_builder(&self.node, name)
                .map_err(|e| EngineError::new(Status::InvalidRequest, e.to_string()))?;
            let service = builder.open().map_err(|e| match e {
                PublishSubscribeOpenError::DoesNotExist => EngineError::new(
                    Status::UnknownCamera,
                    format!(
                        "no camera {name:?} (service {} does not exist)",
                        services::camera_service_name(name)
                            .map(|s| s.as_str().to_owned())
                            .unwrap_or_default()
                    ),
                ),
                e => EngineError::new(
                    Status::Internal,
                    format!("camera {name:?} cannot be opened: {e:?}"),
                ),
            })?;
            // A service without a publisher is a camera whose driver is gone (kept by a frame
            // still in use, or by another process): subscribing would only hold it.
            if service.dynamic_config().number_of_publishers() == 0 {
                return Err(EngineError::new(
                    Status::UnknownCamera,
                    format!("no camera {name:?}: no driver publishes on it"),
                ));
            }
            let subscriber = service.subscriber_builder().create().map_err(|e| {
                EngineError::new(
                    Status::Internal,
                    format!("camera {name:?} cannot be subscribed to: {e:?}"),
                )
            })?;
            tracing::info!(camera = name, "subscribed to camera");
            self.cameras.insert(
                name.to_owned(),
                Camera {
                    newest: None,
                    subscriber,
                    service,
                    driverless_since: None,
                },
            );
        }
        Ok(self.cameras.get_mut(name).expect("camera inserted above"))
    }

    // ---------------------------------------------------------------- detect

    fn take_detect_requests(&mut self) {
        if self.startup.is_some() {
            // They wait in their channels until every model of the folder is there: a request
            // for a model not yet loaded would be refused "unknown object".
            return;
        }
        loop {
            match self.detect_server.receive() {
                Ok(Some(active)) => self.accept(active),
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(error = ?e, "receiving detect requests failed");
                    break;
                }
            }
        }
    }

    fn accept(&mut self, active: DetectActive) {
        let received_ns = monotonic_now_ns();
        self.stats.requests_received += 1;
        let header = *active.user_header();
        let payload_len = active.payload().len();
        tracing::debug!(request = header.request_id, objects = ?header.objects(), "request received");
        if self.shutting_down {
            let e = EngineError::new(Status::ShuttingDown, "the daemon is shutting down");
            return self.refuse(active, &header, received_ns, e);
        }
        let source = match header.validate(payload_len) {
            Ok(source) => source,
            Err(e) => {
                let value = match e {
                    ppfd_protocol::ProtocolError::Version { expected, .. } => expected as u64,
                    _ => 0,
                };
                let error = EngineError {
                    status: e.status(),
                    message: e.to_string(),
                    value,
                };
                return self.refuse(active, &header, received_ns, error);
            }
        };
        let models = match self.registry.resolve(header.objects()) {
            Ok(models) => models,
            Err(e) => return self.refuse(active, &header, received_ns, e),
        };
        if self.queue.len() >= self.config.queue_capacity {
            let e = EngineError::new(
                Status::Busy,
                format!(
                    "{} requests are already waiting; retry later",
                    self.queue.len()
                ),
            );
            return self.refuse(active, &header, received_ns, e);
        }
        self.queue.push_back(Queued {
            active,
            header,
            source,
            models,
            received_ns,
        });
    }

    fn dispatch(&mut self) {
        while self.in_flight.len() < self.config.parallel_detections {
            let Some(q) = self.queue.pop_front() else {
                break;
            };
            if !self.responder.detect_client_alive(&q.active) {
                let outcome = self.responder.abandon(q.active, q.header.request_id);
                self.count(outcome);
                continue;
            }
            if !q.active.is_connected() {
                self.stats.requests_abandoned += 1;
                tracing::debug!(
                    request = q.header.request_id,
                    "client gone before its detection started"
                );
                continue;
            }
            let now = monotonic_now_ns();
            if q.header.deadline_ns != 0 && now >= q.header.deadline_ns {
                self.stats.requests_expired += 1;
                let late = now - q.header.deadline_ns;
                let e = EngineError::new(
                    Status::DeadlineExceeded,
                    format!(
                        "deadline passed {:.3} ms before a worker was free",
                        late as f64 / 1e6
                    ),
                );
                self.refuse(q.active, &q.header, q.received_ns, e);
                continue;
            }
            if let Err(e) = self.start(q) {
                let (active, header, received_ns, error) = *e;
                self.refuse(active, &header, received_ns, error);
            }
        }
    }

    /// Resolves the frame and starts the job; gives the request back with the reason it could
    /// not start.
    #[allow(clippy::type_complexity)]
    fn start(
        &mut self,
        q: Queued,
    ) -> Result<(), Box<(DetectActive, DetectRequestHeader, u64, EngineError)>> {
        let now = monotonic_now_ns();
        let max_age_ns = if q.header.max_frame_age_ns != 0 {
            q.header.max_frame_age_ns
        } else {
            self.config.max_frame_age_ms.saturating_mul(1_000_000)
        };
        let (frame_header, depth, hold) = match &q.source {
            FrameSource::Inline => {
                if let Some(e) = stamped_ahead(&q.header.inline_frame, now, "the frame is") {
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let payload = q.active.payload();
                (
                    q.header.inline_frame,
                    SharedDepth {
                        ptr: payload.as_ptr(),
                        len: payload.len(),
                    },
                    None,
                )
            }
            FrameSource::Camera(name) => {
                let camera = match self.open_camera(name) {
                    Ok(c) => c,
                    Err(e) => return Err(Box::new((q.active, q.header, q.received_ns, e))),
                };
                let arrived = camera.refresh(name);
                let newest = camera.newest.clone();
                self.stats.frames_received += arrived;
                let Some(sample) = newest else {
                    let e = EngineError::new(
                        Status::NoFrame,
                        format!("camera {name:?} has published no frame yet"),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                };
                let fh = *sample.user_header();
                if let Err(e) = fh.validate(sample.payload().len()) {
                    let e = EngineError::new(
                        e.status(),
                        format!("camera {name:?} published a bad frame: {e}"),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let whose = format!("camera {name:?} has its frames");
                if let Some(e) = stamped_ahead(&fh, now, &whose) {
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let age = now.saturating_sub(fh.capture_time_ns);
                if age > max_age_ns {
                    let e = EngineError {
                        status: Status::CameraStale,
                        message: format!(
                            "camera {name:?} is stale: its newest frame (sequence {}) is {:.1} ms old, the limit is {:.1} ms",
                            fh.sequence,
                            age as f64 / 1e6,
                            max_age_ns as f64 / 1e6
                        ),
                        value: age,
                    };
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let payload = sample.payload();
                let depth = SharedDepth {
                    ptr: payload.as_ptr(),
                    len: payload.len(),
                };
                (fh, depth, Some(sample))
            }
        };
        let frame_age_ns = if frame_header.capture_time_ns != 0 {
            now.saturating_sub(frame_header.capture_time_ns)
        } else {
            0
        };

        let job = self.next_job;
        self.next_job += 1;
        let engine = self.engine.clone();
        let models = q.models;
        let cancel = Arc::new(AtomicBool::new(false));
        let options = DetectOptions {
            hypotheses_per_object: q.header.hypotheses_per_object as usize,
            deadline: (q.header.deadline_ns != 0).then(|| instant_of(q.header.deadline_ns)),
            cancel: cancel.clone(),
        };
        let done = self.done_tx.clone();
        let signaller = self.signaller;
        let responder = self.responder.clone();
        let (active, header, received_ns) = (q.active, q.header, q.received_ns);
        let client = active.origin();
        let request_id = header.request_id;
        self.pool.spawn(move || {
            let started_ns = monotonic_now_ns();
            let _span = tracing::debug_span!("detect", request = request_id).entered();
            // SAFETY: see `SharedDepth`: a camera sample stays alive and unchanged on the I/O
            // thread until it has received this job's completion; an inline frame lies in
            // `active`, which this job drops only after the detection.
            let depth = unsafe { depth.values() };
            let frame = FrameView {
                width: frame_header.width,
                height: frame_header.height,
                intrinsics: frame_header.intrinsics,
                depth_scale_mm: frame_header.depth_scale_mm,
                depth,
            };
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                engine.detect(&frame, &models, &options)
            }))
            .unwrap_or_else(|_| {
                Err(EngineError::new(
                    Status::Internal,
                    "the detection failed unexpectedly (panic)",
                ))
            });
            let served = Served {
                header,
                received_ns,
                frame_sequence: frame_header.sequence,
                frame_age_ns,
                started_ns,
                finished_ns: monotonic_now_ns(),
            };
            // Answered from here: the client does not wait for the I/O thread to wake up. The
            // request (and an inline frame in it) is released only after the answer.
            let outcome = responder.answer(active, &served, result);
            // The receiver lives as long as the daemon, which waits for every job.
            let _ = done.send(Completion { job, outcome });
            signaller.signal();
        });
        self.in_flight.insert(
            job,
            InFlight {
                _frame: hold,
                client,
                cancel,
            },
        );
        Ok(())
    }

    /// Records what the worker did with its request and releases the frame it read.
    fn finish(&mut self, c: Completion) {
        self.in_flight.remove(&c.job);
        self.count(c.outcome);
    }

    fn count(&mut self, outcome: Outcome) {
        match outcome {
            Outcome::Served {
                total_ns,
                overhead_ns,
                detection_ns,
            } => self
                .stats
                .record_served(total_ns, overhead_ns, detection_ns),
            Outcome::Undelivered => {}
            Outcome::Refused => self.stats.requests_refused += 1,
            Outcome::Abandoned => self.stats.requests_abandoned += 1,
        }
    }

    fn refuse(
        &mut self,
        active: DetectActive,
        request: &DetectRequestHeader,
        received_ns: u64,
        e: EngineError,
    ) {
        let outcome = self.responder.refuse(active, request, received_ns, e);
        self.count(outcome);
    }

    // ---------------------------------------------------------------- control

    fn take_control_requests(&mut self) {
        loop {
            match self.control_server.receive() {
                Ok(Some(active)) => self.control(active),
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(error = ?e, "receiving control requests failed");
                    break;
                }
            }
        }
    }

    fn control(&mut self, active: ControlActive) {
        let request = *active.payload();
        if let Err(e) = ppfd_protocol::check_version(request.protocol_version) {
            return self.control_answer(active, Status::ProtocolVersion, &e.to_string(), &[]);
        }
        let Some(command) = ControlCommand::from_code(request.command) else {
            let m = format!("unknown control command {}", request.command);
            return self.control_answer(active, Status::InvalidRequest, &m, &[]);
        };
        // Reads (listing, statistics) are polled by monitors: only changes go into the log.
        if matches!(
            command,
            ControlCommand::LoadModel | ControlCommand::DropModel
        ) {
            tracing::info!(?command, object_id = request.object_id, path = %request.path(), "control request");
        } else {
            tracing::debug!(?command, "control request");
        }
        if self.startup.is_some() && !matches!(command, ControlCommand::Statistics) {
            // Listed, loaded or dropped once the models folder is: a load now could be undone
            // by a file of the folder with the same id.
            self.held_control.push(active);
            return;
        }
        if self.shutting_down
            && matches!(
                command,
                ControlCommand::LoadModel | ControlCommand::DropModel
            )
        {
            let m = "the daemon is shutting down";
            return self.control_answer(active, Status::ShuttingDown, m, &[]);
        }
        match command {
            ControlCommand::ListModels => {
                let infos = self.registry.infos();
                let shown = &infos[..infos.len().min(limits::MAX_LISTED_MODELS)];
                self.control_answer(active, Status::Ok, "", shown);
            }
            ControlCommand::Statistics => {
                // The message field holds MESSAGE_BYTES - 1 bytes and a NUL.
                let loading = self
                    .startup
                    .as_ref()
                    .map(|s| format!("\n{}", s.progress()))
                    .unwrap_or_default();
                let mut m = self
                    .config
                    .detector_summary(ppfd_protocol::MESSAGE_BYTES - 1 - loading.len());
                m.push_str(&loading);
                self.control_answer(active, Status::Ok, &m, &[])
            }
            ControlCommand::DropModel => match self.registry.remove(request.object_id) {
                Some(model) => {
                    let m = format!(
                        "dropped object {} ({})",
                        request.object_id,
                        model.info.name()
                    );
                    self.control_answer(active, Status::Ok, &m, &[model.info]);
                }
                None => {
                    let m = format!("no model with object id {} is loaded", request.object_id);
                    self.control_answer(active, Status::UnknownObject, &m, &[]);
                }
            },
            ControlCommand::LoadModel => {
                let path = PathBuf::from(request.path().into_owned());
                if request.path().is_empty() {
                    return self.control_answer(
                        active,
                        Status::InvalidRequest,
                        "LoadModel needs a path",
                        &[],
                    );
                }
                if path.is_relative() {
                    let m = format!(
                        "{} is a relative path, and ppfd's working directory is not the \
                         caller's: give an absolute path",
                        path.display()
                    );
                    return self.control_answer(active, Status::InvalidRequest, &m, &[]);
                }
                if path.exists() && !path.is_dir() && !path.is_file() {
                    // A FIFO or a device: reading it could block the loading thread forever.
                    let m = format!(
                        "{} is not a regular file: give one model file (.ppfm) or mesh (.ply)",
                        path.display()
                    );
                    return self.control_answer(active, Status::ModelError, &m, &[]);
                }
                if path.is_dir() {
                    let m = format!(
                        "{} is a folder: give one model file (.ppfm) or mesh (.ply); a folder \
                         of models is loaded at start (ppfd --models)",
                        path.display()
                    );
                    return self.control_answer(active, Status::ModelError, &m, &[]);
                }
                let object_id = (request.object_id != 0).then_some(request.object_id);
                let job = self.next_job;
                self.next_job += 1;
                self.control_pending.insert(job, active);
                let engine = self.engine.clone();
                let cache = Some(self.config.model_cache_dir());
                let tx = self.loaded_tx.clone();
                let signaller = self.signaller;
                // Building a model from a mesh may take seconds: off the I/O thread and off the
                // detection workers.
                let spawned =
                    std::thread::Builder::new()
                        .name("ppfd-load".into())
                        .spawn(move || {
                            block_termination_signals();
                            let result =
                                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                                    engine.load(&path, object_id, cache.as_deref())
                                }))
                                .unwrap_or_else(|_| {
                                    Err(EngineError::new(
                                        Status::Internal,
                                        "loading failed unexpectedly (panic)",
                                    ))
                                });
                            let _ = tx.send(ModelLoaded { job, result });
                            signaller.signal();
                        });
                if let Err(e) = spawned {
                    if let Some(active) = self.control_pending.remove(&job) {
                        self.control_answer(
                            active,
                            Status::Internal,
                            &format!("cannot start loading: {e}"),
                            &[],
                        );
                    }
                }
            }
        }
    }

    fn finish_load(&mut self, m: ModelLoaded) {
        let Some(active) = self.control_pending.remove(&m.job) else {
            return;
        };
        match m.result.and_then(Registry::with_valid_id) {
            Ok(model) => {
                let info = model.info;
                // Named: a model file asked for by name may come from the mesh beside it.
                let source = model.source.display().to_string();
                let replaced = self.registry.insert(model).is_some();
                let msg = format!(
                    "{} object {} ({}), {} bytes, from {source}",
                    if replaced { "replaced" } else { "loaded" },
                    info.object_id,
                    info.name(),
                    info.byte_size
                );
                tracing::info!("{msg}");
                self.control_answer(active, Status::Ok, &msg, &[info]);
            }
            Err(e) => {
                let status = if e.status == Status::Internal {
                    Status::Internal
                } else {
                    Status::ModelError
                };
                self.control_answer(active, status, &e.message, &[]);
            }
        }
    }

    fn control_answer(
        &mut self,
        active: ControlActive,
        status: Status,
        message: &str,
        models: &[ModelInfo],
    ) {
        if !self.responder.control_client_alive(&active) {
            // As for detect requests: never touch a dead client's possibly reused channel.
            self.responder.abandon_control(active);
            return;
        }
        let mut stats = self.stats.snapshot();
        stats.cameras = self.cameras.len() as u64;
        stats.models_loaded = self.registry.len() as u64;
        stats.model_bytes = self.registry.bytes();
        stats.in_flight = self.in_flight.len() as u64;
        stats.queued = self.queue.len() as u64;
        let header = ControlResponseHeader {
            status: status.code(),
            request_id: active.payload().request_id,
            stats,
            message: text::encode_truncated(message),
            ..Default::default()
        };
        let token = active.payload().reply_token;
        match active.loan_slice_uninit(models.len()) {
            Ok(loaned) => {
                let mut response = loaned.write_from_slice(models);
                *response.user_header_mut() = header;
                if let Err(e) = response.send() {
                    tracing::debug!(error = ?e, "control response not delivered");
                    return;
                }
                self.responder.notify_reply(token);
            }
            Err(e) => tracing::warn!(error = ?e, "cannot loan a control response"),
        }
    }

    // ---------------------------------------------------------------- shutdown

    fn shutdown(&mut self) {
        self.shutting_down = true;
        self.stop_startup();
        for active in std::mem::take(&mut self.held_control) {
            let m = "the daemon is shutting down";
            self.control_answer(active, Status::ShuttingDown, m, &[]);
        }
        while let Some(q) = self.queue.pop_front() {
            let e = EngineError::new(Status::ShuttingDown, "the daemon is shutting down");
            self.refuse(q.active, &q.header, q.received_ns, e);
        }
        self.join_in_flight();
        let pending: Vec<ControlActive> = self.control_pending.drain().map(|(_, a)| a).collect();
        for active in pending {
            self.control_answer(
                active,
                Status::ShuttingDown,
                "the daemon is shutting down",
                &[],
            );
        }
    }

    /// Waits until no worker reads shared memory any more (each answers its request first).
    /// While shutting down, requests that come in meanwhile are answered (statistics, the model
    /// list) or refused "shutting down", not left to time out.
    fn join_in_flight(&mut self) {
        let mut last_warning = Instant::now();
        while !self.in_flight.is_empty() {
            match self.done_rx.recv_timeout(Duration::from_millis(50)) {
                Ok(c) => self.finish(c),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if last_warning.elapsed() >= Duration::from_secs(5) {
                        last_warning = Instant::now();
                        tracing::warn!(
                            running = self.in_flight.len(),
                            "waiting for running detections"
                        );
                    }
                }
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
            }
            if self.shutting_down {
                self.take_detect_requests();
                self.take_control_requests();
            }
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        // The loader signals the I/O thread's eventfd: end it while that is open.
        self.stop_startup();
        // Workers read the frames held in `in_flight`: never release them under a worker.
        self.join_in_flight();
    }
}

/// A frame stamped further than this ahead of the daemon's clock was not stamped with it.
/// Stamps taken by the driver just after the daemon read its clock are a few microseconds
/// ahead; a driver stamping wall-clock time is decades ahead.
const MAX_STAMP_AHEAD_NS: u64 = 1_000_000_000;

/// The refusal of a frame stamped more than [`MAX_STAMP_AHEAD_NS`] ahead of `now`; `whose`
/// begins the message ("the frame is", "camera \"x\" has its frames").
fn stamped_ahead(frame: &FrameHeader, now: u64, whose: &str) -> Option<EngineError> {
    let ahead = frame.capture_time_ns.saturating_sub(now);
    (ahead > MAX_STAMP_AHEAD_NS).then(|| {
        EngineError::new(
            Status::InvalidFrame,
            format!(
                "{whose} stamped {} ahead of this machine's monotonic clock, so frame age \
                 cannot be told: capture_time_ns must be CLOCK_MONOTONIC nanoseconds \
                 (ppfd_protocol::clock::monotonic_now_ns), not wall-clock time, or 0 when unknown",
                duration_text(ahead)
            ),
        )
    })
}

/// `ns` for a message: in seconds up to two minutes, hours up to two days, else days.
fn duration_text(ns: u64) -> String {
    let s = ns as f64 / 1e9;
    if s < 120.0 {
        format!("{s:.1} s")
    } else if s < 48.0 * 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else {
        format!("{:.0} days", s / 86400.0)
    }
}
