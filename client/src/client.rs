//! The robot side: detect requests and control requests.

use std::cell::Cell;
use std::time::{Duration, Instant};

use iceoryx2::node::{Node, NodeView};
use iceoryx2::port::client::Client as IoxClient;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;

use ppfd_protocol::clock::{instant_after, monotonic_now_ns};
use ppfd_protocol::control::{
    ControlCommand, ControlRequest, ControlResponseHeader, DaemonStats, ModelInfo,
};
use ppfd_protocol::detect::{
    flags, DetectCounts, DetectRequestHeader, DetectResponseHeader, LatencyBreakdown, PoseHint,
    PoseHypothesis, Requirements, Status,
};
use ppfd_protocol::frame::FrameHeader;
use ppfd_protocol::services::{self, wake, ControlService, DetectService, EventService};
use ppfd_protocol::text;

use crate::{iceoryx_config, transport, Error, Result};

/// The error of a client port that could not be made; the one of a daemon that serves as many
/// clients as it can says so.
fn client_port(
    what: &'static str,
    max: usize,
) -> impl FnOnce(iceoryx2::service::port_factory::client::ClientCreateError) -> Error {
    use iceoryx2::service::port_factory::client::ClientCreateError;
    move |e| match e {
        ClientCreateError::ExceedsMaxSupportedClients => Error::TooManyClients { what, max },
        e => transport(what)(e),
    }
}

/// The error of a request/response service that could not be opened; one whose messages have
/// another layout than this client's, as a daemon of another protocol version serves them,
/// says so.
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
            Error::Transport(format!("cannot open {service}: {e:?}"))
        }
    }
}

/// How often a client waiting for an answer checks that the daemon still holds its request (an
/// answer wakes it at once; a request let go of does not).
const HELD_CHECK_PERIOD: Duration = Duration::from_millis(50);

/// How often a client waiting for an answer checks that the daemon's process is alive. A
/// daemon that is killed never lets go of its requests: without this check its clients would
/// wait out their timeouts. Each check lists the prefix's iceoryx2 nodes (a directory read and
/// a lock test per node).
const ALIVE_CHECK_PERIOD: Duration = Duration::from_millis(250);

type Ipc = ipc::Service;
type DetectPort =
    IoxClient<Ipc, [u16], DetectRequestHeader, [PoseHypothesis], DetectResponseHeader>;
type DetectRequest = iceoryx2::request_mut::RequestMut<
    Ipc,
    [u16],
    DetectRequestHeader,
    [PoseHypothesis],
    DetectResponseHeader,
>;
type ControlPort = IoxClient<Ipc, ControlRequest, (), [ModelInfo], ControlResponseHeader>;

/// How a [`Client`] connects.
#[derive(Debug, Clone)]
pub struct ClientOptions {
    /// iceoryx2 prefix of the daemon (see `ppfd --prefix`); `None` (the default): `PPFD_PREFIX`
    /// at connect, else iceoryx2's default, as the daemon takes its own. A value of the variable
    /// the daemon would refuse is refused with the variable's name.
    pub prefix: Option<String>,
    /// Depth values of the largest inline frame this client will send (0 if it only names
    /// cameras). Preallocated in shared memory; larger frames grow it.
    pub inline_frame_capacity: usize,
    /// Timeout of control requests, above 0 (zero is refused at connect). A model load can
    /// take longer (a large mesh builds for seconds to minutes): see [`Client::load_model`].
    pub control_timeout: Duration,
    /// Whether the client detects (the default). A client that only sends control requests
    /// (statistics, the model list, loads) says `false`: it takes no detect port, so it
    /// connects while the daemon serves its most detect clients
    /// ([`services::limits::MAX_CONTROL_CLIENTS`]), and its detect calls return
    /// [`Error::ControlOnly`].
    pub detects: bool,
}

impl Default for ClientOptions {
    fn default() -> Self {
        ClientOptions {
            prefix: None,
            inline_frame_capacity: 0,
            control_timeout: Duration::from_secs(5),
            detects: true,
        }
    }
}

/// Per-request options of [`Client::detect`] and [`Client::detect_inline`].
#[derive(Debug, Clone)]
pub struct DetectOptions {
    /// Best hypotheses wanted per object (1 to 16).
    pub hypotheses_per_object: u32,
    /// How long to wait for the answer; also sent as the request's deadline. The default, 3 s,
    /// is about six times what eight objects in a cluttered VGA frame take on two cores
    /// (0.51 s on the LM-O frame, docs/BENCHMARKS.md): room for a busy host, larger frames and
    /// a diagnosis (twice the time), and a hung cycle still ends within a few picking cycles.
    /// Zero is refused.
    pub timeout: Duration,
    /// Oldest acceptable camera frame (`None`: the daemon's limit; zero is refused).
    pub max_frame_age: Option<Duration>,
    /// What the hypotheses must satisfy (minimum score, instance distance, region of
    /// interest, pose restriction), and their order; the default asks for nothing.
    pub requirements: Requirements,
    /// Poses the objects are expected near, at most [`ppfd_protocol::MAX_HINTS_PER_REQUEST`],
    /// each a pose of one of the requested objects: for example the previous cycle's answers
    /// (`PoseHint::from(&hypothesis)`). A hinted object is first looked for from its hints
    /// alone (ICP, re-scoring, the filters and the `requirements`); only the objects with a
    /// hint that fails (or with none) go through voting. Poses from hints carry
    /// [`checks::HINT`](crate::checks::HINT).
    pub hints: Vec<PoseHint>,
    /// Poses the objects are believed at, to diagnose against (empty: no diagnosis). The
    /// detection then runs from scratch (a request cannot carry hints as well), and
    /// [`Detections::diagnosis`] says, per object with such a pose, after each stage where the
    /// best candidate near it stands and at which stage it was lost. The stages run a second
    /// time for this: a diagnosing request takes about twice as long.
    pub diagnose: Vec<PoseHint>,
}

impl Default for DetectOptions {
    fn default() -> Self {
        DetectOptions {
            hypotheses_per_object: 1,
            timeout: Duration::from_secs(3),
            max_frame_age: None,
            requirements: Requirements::default(),
            hints: Vec::new(),
            diagnose: Vec::new(),
        }
    }
}

/// Where the time of one request went, as the client saw it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Latency {
    /// The daemon's breakdown (transport there, queue wait, each stage, detection, total).
    pub daemon: LatencyBreakdown,
    /// Daemon sends the response → this client has it, ns.
    pub response_transport_ns: u64,
    /// Client send → client has the response, ns.
    pub end_to_end_ns: u64,
}

impl Latency {
    /// End to end minus detection time: transport both ways, queueing and the daemon's glue.
    pub fn overhead_ns(&self) -> u64 {
        self.end_to_end_ns.saturating_sub(self.daemon.detection_ns)
    }

    /// The daemon's hand-back: detection finished → response sent, ns (the worker writes and
    /// sends the answer itself). What the overhead holds besides transport, queue wait and
    /// response transport.
    pub fn hand_back_ns(&self) -> u64 {
        self.overhead_ns()
            .saturating_sub(self.daemon.transport_ns)
            .saturating_sub(self.daemon.queue_wait_ns)
            .saturating_sub(self.response_transport_ns)
    }
}

/// The answer to a detect request.
#[derive(Debug, Clone, PartialEq)]
pub struct Detections {
    /// The request's id.
    pub request_id: u64,
    /// Hypotheses grouped by object in request order; within an object, in the order the
    /// request asked for ([`Requirements::order`]: best score first by default, or nearest
    /// first), those that passed the filters before those that did not.
    pub hypotheses: Vec<PoseHypothesis>,
    /// Where the time went.
    pub latency: Latency,
    /// Sizes of the work.
    pub counts: DetectCounts,
    /// Sequence number of the frame used.
    pub frame_sequence: u64,
    /// Age of that frame when detection started, ns.
    pub frame_age_ns: u64,
    /// With [`DetectOptions::diagnose`]: per object diagnosed, a heading line ("object 5:
    /// lost at voting") and one line per stage; empty otherwise.
    pub diagnosis: String,
}

impl Detections {
    /// The hypotheses of one object, in the order of [`Detections::hypotheses`].
    pub fn of(&self, object_id: u32) -> impl Iterator<Item = &PoseHypothesis> {
        self.hypotheses
            .iter()
            .filter(move |h| h.object_id == object_id)
    }

    /// The best-scored hypothesis of one object.
    pub fn best(&self, object_id: u32) -> Option<&PoseHypothesis> {
        self.of(object_id)
            .max_by(|a, b| a.score.total_cmp(&b.score))
    }
}

/// A connection to the daemon's services. Not `Send`: one per thread.
pub struct Client {
    detect: Option<DetectPort>,
    control: ControlPort,
    wake: Notifier<Ipc>,
    replies: Listener<Ipc>,
    reply_token: u64,
    next_request: Cell<u64>,
    control_timeout: Duration,
    /// The iceoryx2 prefix, for messages.
    prefix: String,
    _detect_service: DetectService<Ipc>,
    _control_service: ControlService<Ipc>,
    _wake_service: EventService<Ipc>,
    _replies_service: EventService<Ipc>,
    _node: Node<Ipc>,
    /// Asked while waiting for an answer (after each wait, at most [`HELD_CHECK_PERIOD`] apart,
    /// and when a signal interrupts one): `true` ends the wait with [`Error::Interrupted`];
    /// without one, the wait goes on.
    interrupt_check: Option<InterruptCheck>,
}

/// A caller's check, run while a request waits for its answer (after each slice of the wait,
/// at most 50 ms apart, and when a signal interrupts one): `true` stops waiting.
pub type InterruptCheck = Box<dyn Fn() -> bool>;

/// Whether the daemon's process still lives, checked every [`ALIVE_CHECK_PERIOD`] while a
/// client waits.
struct AliveCheck {
    next: Instant,
}

impl AliveCheck {
    fn new() -> Self {
        AliveCheck {
            next: Instant::now() + ALIVE_CHECK_PERIOD,
        }
    }

    /// True once the daemon that took a request sent at `send_ns` has gone
    /// ([`daemon_gone_since`]), looked at once per [`ALIVE_CHECK_PERIOD`]. A listing that
    /// fails counts as alive: the timeout still ends the wait.
    fn daemon_gone(&mut self, service: &DetectService<Ipc>, send_ns: u64) -> bool {
        if Instant::now() < self.next {
            return false;
        }
        self.next = Instant::now() + ALIVE_CHECK_PERIOD;
        daemon_gone_since(service, send_ns)
    }
}

/// Whether the daemon that took a request sent at `send_ns` has gone: no live node of the
/// daemon's name attached to the detect service was made before the request was sent (a node
/// whose state cannot be read counts as alive). A daemon restarted at once (as systemd's
/// `Restart=` does) is attached again, but it never took the request. Only the service's nodes
/// (the daemon and its clients) are listed, not every node on the host: the check runs on the
/// waiting thread, and a host whose node folder held 2 500 entries (dead processes of other
/// prefixes) held an answer back by up to 30 ms while the whole folder was read. Node ids hold
/// their creation time on `CLOCK_MONOTONIC`, the clock of `send_ns`.
fn daemon_gone_since(service: &DetectService<Ipc>, send_ns: u64) -> bool {
    let mut held_by_a_live_daemon = false;
    let listed = service.nodes(|state| {
        let made_before = match &state {
            NodeState::Alive(view) => view.id().creation_time::<Ipc>().map_or(true, |t| {
                t.seconds() * 1_000_000_000 + u64::from(t.nanoseconds()) <= send_ns
            }),
            _ => true,
        };
        held_by_a_live_daemon = services::may_be_the_daemon(&state) && made_before;
        if held_by_a_live_daemon {
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    });
    listed.is_ok() && !held_by_a_live_daemon
}

fn new_token() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    // Unique per process and client; the daemon matches it to this client's listener name.
    let t = ((std::process::id() as u64) << 32) ^ (monotonic_now_ns() & 0xffff_ffff) ^ (n << 24);
    t.max(1)
}

impl Client {
    /// Connects with default options (prefix from `PPFD_PREFIX`).
    pub fn connect() -> Result<Client> {
        Self::connect_with(&ClientOptions::default())
    }

    /// Connects. Works before the daemon starts: requests then fail with [`Error::NoDaemon`]
    /// until it serves, and the same client keeps working across daemon restarts.
    pub fn connect_with(options: &ClientOptions) -> Result<Client> {
        above_zero("control timeout", options.control_timeout)?;
        let config = iceoryx_config(options.prefix.as_deref())?;
        let node = NodeBuilder::new()
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(transport("cannot create an iceoryx2 node"))?;
        let detect_service = services::detect_builder(&node)
            .open_or_create()
            .map_err(open_service(services::DETECT))?;
        let detect = if options.detects {
            let port = detect_service
                .client_builder()
                .initial_max_slice_len(options.inline_frame_capacity.max(1))
                .allocation_strategy(AllocationStrategy::PowerOfTwo)
                .create()
                .map_err(client_port(
                    "cannot create a ppfd/detect client",
                    services::limits::MAX_CLIENTS,
                ))?;
            Some(port)
        } else {
            None
        };
        let control_service = services::control_builder(&node)
            .open_or_create()
            .map_err(open_service(services::CONTROL))?;
        let control = control_service
            .client_builder()
            .create()
            .map_err(client_port(
                "cannot create a ppfd/control client",
                services::limits::MAX_CONTROL_CLIENTS,
            ))?;
        let wake_service = services::daemon_wake_builder(&node)
            .open_or_create()
            .map_err(transport("cannot open ppfd/daemon"))?;
        let wake = wake_service
            .notifier_builder()
            .create()
            .map_err(transport("cannot notify ppfd/daemon"))?;
        let replies_service = services::responses_builder(&node)
            .open_or_create()
            .map_err(transport("cannot open ppfd/responses"))?;
        let reply_token = new_token();
        let name = PortName::new(&services::reply_listener_name(reply_token))
            .map_err(transport("reply listener name"))?;
        let replies = replies_service
            .listener_builder()
            .name(&name)
            .create()
            .map_err(transport("cannot listen on ppfd/responses"))?;
        Ok(Client {
            detect,
            control,
            wake,
            replies,
            reply_token,
            // Ids unique across clients: a response can never be taken for another client's.
            next_request: Cell::new(reply_token.rotate_left(24) & !0xff_ffff),
            control_timeout: options.control_timeout,
            prefix: config.global.prefix.to_string(),
            _detect_service: detect_service,
            _control_service: control_service,
            _wake_service: wake_service,
            _replies_service: replies_service,
            _node: node,
            interrupt_check: None,
        })
    }

    fn request_id(&self) -> u64 {
        let id = self.next_request.get();
        self.next_request.set(id + 1);
        id
    }

    /// Detects `objects` in the newest frame of `camera` (from [`DetectOptions::hints`] first,
    /// where it has any).
    pub fn detect(
        &self,
        camera: &str,
        objects: &[u32],
        options: &DetectOptions,
    ) -> Result<Detections> {
        services::check_camera_name(camera)?;
        let mut header = self.request_header(objects, options)?;
        header.camera_name = text::encode_name("camera", camera)?;
        header.validate(0)?;
        let request = self
            .detect_port()?
            .loan_slice_uninit(0)
            .map_err(transport("cannot loan a request"))?;
        let mut request = request.write_from_fn(|_| 0);
        *request.user_header_mut() = header;
        self.send_detect(request, options.timeout)
    }

    /// Detects `objects` in a frame this process owns: `frame` describes it, `depth` holds its
    /// `width × height` values, written straight into the request's shared memory.
    pub fn detect_inline(
        &self,
        frame: &FrameHeader,
        depth: &[u16],
        objects: &[u32],
        options: &DetectOptions,
    ) -> Result<Detections> {
        let mut header = self.request_header(objects, options)?;
        header.flags |= flags::INLINE_FRAME;
        header.inline_frame = *frame;
        header.validate(depth.len())?;
        let request = self
            .detect_port()?
            .loan_slice_uninit(depth.len())
            .map_err(transport("cannot loan a request"))?;
        let mut request = request.write_from_slice(depth);
        *request.user_header_mut() = header;
        self.send_detect(request, options.timeout)
    }

    /// Sends a request exactly as given, unchecked (to exercise the daemon's refusals); only
    /// its id, reply token, send time and deadline are set here.
    pub fn send_raw(
        &self,
        header: &DetectRequestHeader,
        depth: &[u16],
        timeout: Duration,
    ) -> Result<Detections> {
        let request = self
            .detect_port()?
            .loan_slice_uninit(depth.len())
            .map_err(transport("cannot loan a request"))?;
        let mut request = request.write_from_slice(depth);
        *request.user_header_mut() = *header;
        self.send_detect(request, timeout)
    }

    /// The detect port, which a client connected with [`ClientOptions::detects`] `false` has
    /// not.
    fn detect_port(&self) -> Result<&DetectPort> {
        self.detect.as_ref().ok_or(Error::ControlOnly)
    }

    fn request_header(
        &self,
        objects: &[u32],
        options: &DetectOptions,
    ) -> Result<DetectRequestHeader> {
        let mut header = DetectRequestHeader {
            hypotheses_per_object: options.hypotheses_per_object,
            requirements: options.requirements,
            ..Default::default()
        };
        header.set_objects(objects)?;
        if options.diagnose.is_empty() {
            header.set_hints(&options.hints)?;
        } else if !options.hints.is_empty() {
            return Err(ppfd_protocol::ProtocolError::DiagnoseWithHints.into());
        } else {
            header.set_diagnosis_poses(&options.diagnose)?;
        }
        above_zero("timeout", options.timeout)?;
        // 0 on the wire takes the daemon's limit, so a zero age is refused here rather than
        // sent as that.
        if options.max_frame_age == Some(Duration::ZERO) {
            return Err(ppfd_protocol::ProtocolError::Requirement {
                field: "maximum frame age",
                value: "0 s".into(),
                expected: "more than 0 (none takes the daemon's limit)".into(),
            }
            .into());
        }
        header.max_frame_age_ns = options
            .max_frame_age
            .map(|d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
            .unwrap_or(0);
        Ok(header)
    }

    fn send_detect(&self, mut request: DetectRequest, timeout: Duration) -> Result<Detections> {
        let request_id = self.request_id();
        let header = request.user_header_mut();
        header.request_id = request_id;
        header.reply_token = self.reply_token;
        let send_ns = monotonic_now_ns();
        header.send_time_ns = send_ns;
        header.deadline_ns =
            send_ns.saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
        let pending = request
            .send()
            .map_err(transport("cannot send the request"))?;
        if pending.number_of_server_connections() == 0 {
            return Err(Error::NoDaemon {
                service: services::DETECT,
                prefix: self.prefix.clone(),
            });
        }
        let _ = self.wake.notify_with_custom_event_id(wake::REQUEST);
        self.await_answer(
            timeout,
            send_ns,
            || pending.is_connected(),
            || {
                while let Some(response) = pending
                    .receive()
                    .map_err(transport("cannot receive the response"))?
                {
                    let received_ns = monotonic_now_ns();
                    let h = *response.user_header();
                    if h.request_id == request_id {
                        return decode_detect(&h, response.payload(), send_ns, received_ns)
                            .map(Some);
                    }
                }
                Ok(None)
            },
        )
    }

    /// Waits up to `timeout` for the answer to a request sent at `send_ns`: `answer` looks
    /// for it, `held` says whether the daemon still holds the request. Ends with the answer, or
    /// [`Error::Dropped`] when the daemon let go of the request without one,
    /// [`Error::DaemonGone`], or [`Error::Timeout`].
    fn await_answer<T>(
        &self,
        timeout: Duration,
        send_ns: u64,
        held: impl Fn() -> bool,
        mut answer: impl FnMut() -> Result<Option<T>>,
    ) -> Result<T> {
        let deadline = instant_after(timeout);
        let mut alive = AliveCheck::new();
        loop {
            // Whether the daemon still holds the request, read before looking for the answer:
            // it answers before it lets go, so an answer sent before is found below.
            let held = held();
            let gone = alive.daemon_gone(&self._detect_service, send_ns);
            if let Some(found) = answer()? {
                return Ok(found);
            }
            if !held {
                // A daemon restarted at once removes its dead predecessor's ports as it
                // starts, which lets go of the request before the periodic check looks.
                return Err(if daemon_gone_since(&self._detect_service, send_ns) {
                    Error::DaemonGone
                } else {
                    Error::Dropped
                });
            }
            if gone {
                return Err(Error::DaemonGone);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(Error::Timeout(timeout));
            }
            self.wait_reply(left.min(HELD_CHECK_PERIOD))?;
        }
    }

    /// Sets what decides, while a request waits for its answer, whether to stop waiting: it is
    /// asked after each slice of the wait (at most 50 ms apart) and when a signal interrupts
    /// one, so a signal that lands between waits or on another thread is seen as well. Without
    /// a check a signal only wakes the wait, which goes on: a program's own
    /// handlers (a watchdog timer, a SIGTERM handler that sets a flag) would otherwise cost it
    /// the request. A binding for a language that runs its handlers between calls (Python)
    /// runs them here, and stops when one raises.
    pub fn set_interrupt_check(&mut self, check: InterruptCheck) {
        self.interrupt_check = Some(check);
    }

    /// Waits up to `left` for a reply's wake-up, then asks the interrupt check. It is asked after
    /// every wait, not only one a signal cut short: a signal that came while this thread was
    /// not waiting (listing the daemon's node, say), or that another thread of the process
    /// took, interrupts no wait, and would otherwise go unseen until the request ends.
    fn wait_reply(&self, left: Duration) -> Result<()> {
        use iceoryx2::port::listener::ListenerWaitError;
        match self.replies.timed_wait(|_| {}, left) {
            // The caller's loop looks for the answer again.
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
            Err(e) => return Err(transport("waiting for the response failed")(e)),
        }
        match &self.interrupt_check {
            Some(check) if check() => Err(Error::Interrupted),
            _ => Ok(()),
        }
    }

    fn control(
        &self,
        command: ControlCommand,
        object_id: u32,
        path: &str,
    ) -> Result<(ControlResponseHeader, Vec<ModelInfo>)> {
        let request = ControlRequest {
            command: command as u32,
            object_id,
            path: text::encode_name("path", path)?,
            ..Default::default()
        };
        self.send_control(request, self.control_timeout)
    }

    /// Sends a control request exactly as given, unchecked (to exercise the daemon's
    /// refusals); only its id and reply token are set here.
    pub fn send_raw_control(
        &self,
        request: &ControlRequest,
        timeout: Duration,
    ) -> Result<(ControlResponseHeader, Vec<ModelInfo>)> {
        self.send_control(*request, timeout)
    }

    fn send_control(
        &self,
        mut request: ControlRequest,
        timeout: Duration,
    ) -> Result<(ControlResponseHeader, Vec<ModelInfo>)> {
        above_zero("timeout", timeout)?;
        request.request_id = self.request_id();
        request.reply_token = self.reply_token;
        let send_ns = monotonic_now_ns();
        let pending = self
            .control
            .send_copy(request)
            .map_err(transport("cannot send the control request"))?;
        if pending.number_of_server_connections() == 0 {
            return Err(Error::NoDaemon {
                service: services::CONTROL,
                prefix: self.prefix.clone(),
            });
        }
        let _ = self.wake.notify_with_custom_event_id(wake::REQUEST);
        self.await_answer(
            timeout,
            send_ns,
            || pending.is_connected(),
            || {
                let Some(response) = pending
                    .receive()
                    .map_err(transport("cannot receive the response"))?
                else {
                    return Ok(None);
                };
                let h = *response.user_header();
                let status = Status::from_code(h.status).unwrap_or(Status::Internal);
                if status != Status::Ok {
                    // A control answer has no value field: the one value a control refusal
                    // has, the unknown object's id, is the request's own.
                    let value = match status {
                        Status::UnknownObject => request.object_id as u64,
                        _ => 0,
                    };
                    return Err(Error::Refused {
                        status,
                        message: h.message().into_owned(),
                        value,
                    });
                }
                Ok(Some((h, response.payload().to_vec())))
            },
        )
    }

    /// The loaded models, by object id; at most
    /// [`MAX_LISTED_MODELS`](ppfd_protocol::services::limits::MAX_LISTED_MODELS) (256) of them,
    /// the lowest ids. [`Client::model_listing`] also says how many are loaded.
    pub fn models(&self) -> Result<Vec<ModelInfo>> {
        Ok(self.model_listing()?.models)
    }

    /// The loaded models as [`Client::models`] lists them, and how many are loaded: more than
    /// listed when the daemon holds more than a listing carries.
    pub fn model_listing(&self) -> Result<ModelListing> {
        let (h, models) = self.control(ControlCommand::ListModels, 0, "")?;
        Ok(ModelListing {
            loaded: (h.stats.models_loaded as usize).max(models.len()),
            models,
        })
    }

    /// Loads a model file (or builds one from a PLY mesh) in the daemon; `path` absolute, as
    /// the daemon sees it; `object_id` 0 takes the id from the file. Bounded by
    /// [`ClientOptions::control_timeout`]; [`Client::load_model_within`] takes a bound of its
    /// own, for a large mesh (its build takes seconds to minutes). A load that times out is not
    /// cancelled: the daemon finishes it and serves the model. Sent again, it would be done
    /// again after it (loads run one at a time); [`Client::stats`] (`model_loads_running`,
    /// `model_loads_waiting`) and [`Client::models`] tell when it is done.
    pub fn load_model(&self, path: &str, object_id: u32) -> Result<ModelInfo> {
        self.load_model_within(path, object_id, self.control_timeout)
    }

    /// [`Client::load_model`], waiting at most `timeout` for the daemon's answer.
    pub fn load_model_within(
        &self,
        path: &str,
        object_id: u32,
        timeout: Duration,
    ) -> Result<ModelInfo> {
        let request = ControlRequest {
            command: ControlCommand::LoadModel as u32,
            object_id,
            path: text::encode_name("path", path)?,
            ..Default::default()
        };
        let (h, models) = self.send_control(request, timeout)?;
        models.first().copied().ok_or_else(|| {
            Error::Transport(format!("load answered without a model: {}", h.message()))
        })
    }

    /// Drops a model from the daemon.
    pub fn drop_model(&self, object_id: u32) -> Result<()> {
        self.control(ControlCommand::DropModel, object_id, "")
            .map(|_| ())
    }

    /// The daemon's statistics.
    pub fn stats(&self) -> Result<DaemonStats> {
        Ok(self.statistics()?.0)
    }

    /// The daemon's statistics, and the detector parameters it runs with as text
    /// (`detector: defaults`, or `detector: voting.reference_step=2 …`). Statistics are
    /// answered while the daemon loads its models folder at start, which hold the other
    /// requests until it is done: [`DaemonStats::startup_files_done`] against
    /// [`DaemonStats::startup_files`] says how far it is.
    pub fn statistics(&self) -> Result<(DaemonStats, String)> {
        let (h, _) = self.control(ControlCommand::Statistics, 0, "")?;
        Ok((h.stats, h.message().into_owned()))
    }
}

fn decode_detect(
    h: &DetectResponseHeader,
    payload: &[PoseHypothesis],
    send_ns: u64,
    received_ns: u64,
) -> Result<Detections> {
    let status = Status::from_code(h.status).ok_or_else(|| Error::Refused {
        status: Status::Internal,
        message: format!("unknown status code {} from the daemon", h.status),
        value: h.status as u64,
    })?;
    if status != Status::Ok {
        return Err(Error::Refused {
            status,
            message: h.message().into_owned(),
            value: h.error_value,
        });
    }
    Ok(Detections {
        request_id: h.request_id,
        hypotheses: payload.to_vec(),
        latency: Latency {
            daemon: h.latency,
            response_transport_ns: received_ns.saturating_sub(h.response_send_ns),
            end_to_end_ns: received_ns.saturating_sub(send_ns),
        },
        counts: h.counts,
        frame_sequence: h.frame_sequence,
        frame_age_ns: h.frame_age_ns,
        diagnosis: h.diagnosis().into_owned(),
    })
}

/// Refuses a zero timeout before anything is sent: a request whose deadline is its send time
/// can only fail (refused "deadline passed", or a timeout while the daemon carries it out).
fn above_zero(field: &'static str, timeout: Duration) -> Result<()> {
    if timeout.is_zero() {
        return Err(ppfd_protocol::ProtocolError::Requirement {
            field,
            value: "0 s".into(),
            expected: "more than 0".into(),
        }
        .into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The request header of protocol version 1, before the request options: a daemon (or
    /// client) of that version opens `ppfd/detect` with it.
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("ppfd::DetectRequestHeader")]
    #[repr(C)]
    struct VersionOneRequestHeader {
        fields: [u64; 38],
    }

    /// A client meeting `ppfd/detect` served with the messages of another protocol version
    /// is told so at `connect`, not given iceoryx2's type error alone.
    #[test]
    fn a_service_of_another_protocol_version_is_named_so_at_connect() {
        let prefix = format!("ppfd_version_test_{}_", std::process::id());
        let config = iceoryx_config(Some(&prefix)).unwrap();
        let node = NodeBuilder::new()
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .unwrap();
        let _old = node
            .service_builder(&ServiceName::new(services::DETECT).unwrap())
            .request_response::<[u16], [PoseHypothesis]>()
            .request_user_header::<VersionOneRequestHeader>()
            .response_user_header::<DetectResponseHeader>()
            .create()
            .unwrap();
        let e = Client::connect_with(&ClientOptions {
            prefix: Some(prefix.clone()),
            ..Default::default()
        })
        .err()
        .expect("connect must fail");
        drop((_old, node));
        let _ = crate::remove_prefix_leftovers(&prefix);
        assert!(
            matches!(e, Error::OtherProtocolVersion { service, .. } if service == services::DETECT),
            "{e:?}"
        );
        let m = e.to_string();
        assert!(
            m.contains("cannot open ppfd/detect") && m.contains("another protocol version"),
            "{m}"
        );
        assert!(
            m.contains(&ppfd_protocol::PROTOCOL_VERSION.to_string()),
            "{m}"
        );
    }

    #[test]
    fn refusals_decode_with_their_status_and_value() {
        let h = DetectResponseHeader {
            status: Status::CameraStale.code(),
            error_value: 1_500_000_000,
            message: text::encode_truncated("camera \"k\" is stale"),
            ..Default::default()
        };
        match decode_detect(&h, &[], 5, 10) {
            Err(Error::Refused {
                status,
                value,
                message,
            }) => {
                assert_eq!(status, Status::CameraStale);
                assert_eq!(value, 1_500_000_000);
                assert!(message.contains("stale"));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn overhead_is_end_to_end_minus_detection() {
        let mut h = DetectResponseHeader::default();
        h.latency.total_ns = 900;
        h.latency.detection_ns = 700;
        h.response_send_ns = 1000;
        let d = decode_detect(&h, &[PoseHypothesis::default()], 100, 1100).unwrap();
        assert_eq!(d.latency.response_transport_ns, 100);
        assert_eq!(d.latency.end_to_end_ns, 1000);
        assert_eq!(d.latency.overhead_ns(), 300);
        assert_eq!(d.hypotheses.len(), 1);
    }

    #[test]
    fn a_zero_control_timeout_is_refused_before_connecting() {
        let options = ClientOptions {
            control_timeout: Duration::ZERO,
            ..Default::default()
        };
        let e = Client::connect_with(&options).err().expect("refused");
        assert_eq!(
            e.to_string(),
            "control timeout 0 s is out of range: expected more than 0"
        );
    }
}

/// What [`Client::model_listing`] answers.
#[derive(Debug, Clone)]
pub struct ModelListing {
    /// The models listed, by object id, at most
    /// [`MAX_LISTED_MODELS`](ppfd_protocol::services::limits::MAX_LISTED_MODELS).
    pub models: Vec<ModelInfo>,
    /// How many models the daemon holds.
    pub loaded: usize,
}

impl ModelListing {
    /// Whether some loaded models are not listed.
    pub fn is_partial(&self) -> bool {
        self.loaded > self.models.len()
    }
}
