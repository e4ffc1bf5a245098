//! The camera-driver side: publish depth frames into shared memory.

use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::{Node, NodeState, NodeView};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;

use ppfd_protocol::clock::monotonic_now_ns;
use ppfd_protocol::frame::{FrameHeader, Intrinsics};
use ppfd_protocol::services::{self, limits, wake, CameraService, EventService};
use ppfd_protocol::text;

use crate::{iceoryx_config, transport, Error, Result};

type Ipc = ipc::Service;

/// The longest [`CameraPublisher::idle`] sleeps before it looks for new subscribers again: a
/// daemon that subscribes while the driver waits gets the newest frame within this.
const IDLE_STEP: Duration = Duration::from_millis(20);

/// Publishes the depth frames of one camera on `ppfd/camera/<name>/depth`. Not `Send`: keep it
/// on the driver's thread.
///
/// The camera keeps its newest frame for a subscriber that comes late (a daemon started after
/// the driver, or one that finds the camera at its next housekeeping round), but hands it over
/// only when the publisher looks for new subscribers: at each frame it sends, and at
/// [`CameraPublisher::update_connections`]. A driver that publishes rarely, or once and then
/// waits, waits with [`CameraPublisher::idle`] instead of sleeping, or the daemon sees no frame
/// until the next one.
pub struct CameraPublisher {
    publisher: Publisher<Ipc, [u16], FrameHeader>,
    template: FrameHeader,
    sequence: u64,
    _wake: Option<Notifier<Ipc>>,
    _service: CameraService<Ipc>,
    _wake_service: Option<EventService<Ipc>>,
    _node: Node<Ipc>,
}

/// A frame being written: depth values in shared memory, not yet initialised.
pub struct FrameLoan<'a> {
    sample: SampleMutUninit<Ipc, [MaybeUninit<u16>], FrameHeader>,
    sequence: &'a mut u64,
}

/// A frame whose depth is written, ready to publish.
pub struct ReadyFrame<'a> {
    sample: SampleMut<Ipc, [u16], FrameHeader>,
    sequence: &'a mut u64,
}

impl CameraPublisher {
    /// Creates the camera's service (or joins it) and tells a running daemon about it.
    /// `prefix` as [`crate::ClientOptions::prefix`] (`None`: `PPFD_PREFIX`, else iceoryx2's
    /// default); `depth_scale_mm` is millimetres per raw depth unit.
    pub fn new(
        prefix: Option<&str>,
        camera: &str,
        camera_id: u32,
        width: u32,
        height: u32,
        intrinsics: Intrinsics,
        depth_scale_mm: f32,
    ) -> Result<CameraPublisher> {
        let template = FrameHeader {
            camera_id,
            camera_name: text::encode_name("camera", camera)?,
            width,
            height,
            intrinsics,
            depth_scale_mm,
            ..FrameHeader::default()
        };
        template.validate(template.pixel_count())?;
        let node = node(prefix)?;
        let service = services::camera_builder(&node, camera)?
            .open_or_create()
            .map_err(transport("cannot open the camera service"))?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(template.pixel_count().max(limits::VGA_PIXELS))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(limits::MAX_LOANED_FRAMES)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| match e {
                PublisherCreateError::ExceedsMaxSupportedPublishers => Error::CameraTaken {
                    camera: camera.to_owned(),
                },
                e => transport("cannot create the camera publisher")(e),
            })?;
        // The second publisher slot is for a driver that replaces a dead one, whose publisher
        // iceoryx2 keeps until someone cleans up after it. Two live drivers would interleave
        // their frames, and the daemon would detect in whichever came last. The check runs
        // after this publisher exists, so that of two drivers starting at once the later one
        // to check sees the other: they are never both let in.
        if another_live_publisher(&service, node.id())? {
            return Err(Error::CameraTaken {
                camera: camera.to_owned(),
            });
        }
        own_publisher_nodes().push(*node.id());
        // Wake a running daemon so that it subscribes before the first frame.
        let wake_service = services::daemon_wake_builder(&node).open_or_create().ok();
        let wake = wake_service
            .as_ref()
            .and_then(|s| s.notifier_builder().create().ok());
        if let Some(n) = &wake {
            let _ = n.notify_with_custom_event_id(wake::CAMERA_APPEARED);
        }
        Ok(CameraPublisher {
            publisher,
            template,
            sequence: 0,
            _wake: wake,
            _service: service,
            _wake_service: wake_service,
            _node: node,
        })
    }

    /// The header every frame starts from.
    pub fn template(&self) -> &FrameHeader {
        &self.template
    }

    /// Loans the next frame's `width × height` depth values in shared memory.
    pub fn loan(&mut self) -> Result<FrameLoan<'_>> {
        let mut sample = self
            .publisher
            .loan_slice_uninit(self.template.pixel_count())
            .map_err(transport("cannot loan a frame"))?;
        *sample.user_header_mut() = self.template;
        Ok(FrameLoan {
            sample,
            sequence: &mut self.sequence,
        })
    }

    /// Hands the newest frame to subscribers that appeared since the last frame was sent (a
    /// daemon that started, or found this camera, meanwhile). Sending a frame does this too;
    /// call it while no frame is sent, or use [`CameraPublisher::idle`].
    pub fn update_connections(&self) -> Result<()> {
        self.publisher
            .update_connections()
            .map_err(transport("cannot connect the camera's new subscribers"))
    }

    /// Waits `duration` without publishing, staying reachable: every 20 ms it hands the newest
    /// frame to subscribers that appeared meanwhile ([`CameraPublisher::update_connections`]).
    /// Use it wherever a driver would sleep: between slow frames, and after its last one.
    pub fn idle(&self, duration: Duration) -> Result<()> {
        let until = Instant::now() + duration;
        loop {
            self.update_connections()?;
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(());
            }
            std::thread::sleep(left.min(IDLE_STEP));
        }
    }

    /// Copies `depth` into a loaned frame and publishes it, captured now.
    pub fn publish(&mut self, depth: &[u16]) -> Result<u64> {
        self.loan()?
            .write_from_slice(depth)?
            .send(monotonic_now_ns())
    }
}

impl<'a> FrameLoan<'a> {
    /// The uninitialised depth values, for a driver that writes them itself; then
    /// [`FrameLoan::assume_init`].
    pub fn depth_uninit(&mut self) -> &mut [MaybeUninit<u16>] {
        self.sample.payload_mut()
    }

    /// Declares every depth value written.
    ///
    /// # Safety
    /// Every element of [`FrameLoan::depth_uninit`] must have been written.
    pub unsafe fn assume_init(self) -> ReadyFrame<'a> {
        // SAFETY: promised by the caller.
        ReadyFrame {
            sample: unsafe { self.sample.assume_init() },
            sequence: self.sequence,
        }
    }

    /// Writes the depth values by index.
    pub fn write_from_fn(self, f: impl FnMut(usize) -> u16) -> ReadyFrame<'a> {
        ReadyFrame {
            sample: self.sample.write_from_fn(f),
            sequence: self.sequence,
        }
    }

    /// Copies the depth values (`width × height` of them).
    pub fn write_from_slice(self, depth: &[u16]) -> Result<ReadyFrame<'a>> {
        let expected = self.sample.payload().len();
        if depth.len() != expected {
            let h = self.sample.user_header();
            return Err(ppfd_protocol::ProtocolError::FrameSize {
                width: h.width,
                height: h.height,
                values: depth.len(),
            }
            .into());
        }
        Ok(ReadyFrame {
            sample: self.sample.write_from_slice(depth),
            sequence: self.sequence,
        })
    }
}

impl ReadyFrame<'_> {
    /// The frame's header (starts as the publisher's template), e.g. to set per-frame
    /// intrinsics.
    pub fn header_mut(&mut self) -> &mut FrameHeader {
        self.sample.user_header_mut()
    }

    /// The depth values, to adjust after writing.
    pub fn depth_mut(&mut self) -> &mut [u16] {
        self.sample.payload_mut()
    }

    /// Publishes the frame, captured at `capture_time_ns` (`CLOCK_MONOTONIC`). Returns its
    /// sequence number.
    pub fn send(mut self, capture_time_ns: u64) -> Result<u64> {
        *self.sequence += 1;
        let header = self.sample.user_header_mut();
        header.sequence = *self.sequence;
        header.capture_time_ns = capture_time_ns;
        self.sample
            .send()
            .map_err(transport("cannot publish the frame"))?;
        Ok(*self.sequence)
    }
}

/// The nodes of this process's live camera publishers. A driver that makes its publisher anew
/// (on a reconnect, or a notebook cell run twice) makes the new one before the old one is
/// dropped; the two are one driver, not two.
static OWN_PUBLISHER_NODES: std::sync::Mutex<Vec<UniqueNodeId>> = std::sync::Mutex::new(Vec::new());

fn own_publisher_nodes() -> std::sync::MutexGuard<'static, Vec<UniqueNodeId>> {
    // A panic elsewhere while the list was held leaves it whole: it is only pushed to and
    // removed from.
    OWN_PUBLISHER_NODES
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Drop for CameraPublisher {
    fn drop(&mut self) {
        let id = *self._node.id();
        own_publisher_nodes().retain(|n| *n != id);
    }
}

/// Whether a publisher of `service` belongs to a live node of another driver: not `own`, and
/// not another publisher of this process. A node whose state cannot be read (another user's)
/// counts as live.
fn another_live_publisher(service: &CameraService<Ipc>, own: &UniqueNodeId) -> Result<bool> {
    let mut publishers = Vec::new();
    {
        let ours = own_publisher_nodes();
        service.dynamic_config().list_publishers(|p| {
            if p.node_id != *own && !ours.contains(&p.node_id) {
                publishers.push(p.node_id);
            }
            CallbackProgression::Continue
        });
    }
    if publishers.is_empty() {
        return Ok(false);
    }
    let mut live = false;
    service
        .nodes(|state| {
            live = match &state {
                NodeState::Alive(view) => publishers.contains(view.id()),
                NodeState::Inaccessible(id) => publishers.contains(id),
                NodeState::Dead(_) | NodeState::Undefined(_) => false,
            };
            if live {
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        })
        .map_err(transport("cannot list the camera's drivers"))?;
    Ok(live)
}

/// A node of its own under `prefix`, for one camera port.
fn node(prefix: Option<&str>) -> Result<Node<Ipc>> {
    NodeBuilder::new()
        .config(&iceoryx_config(prefix)?)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(transport("cannot create an iceoryx2 node"))
}

/// Reads a camera's frames beside the daemon (a viewer or recorder; a camera takes
/// [`limits::MAX_CAMERA_SUBSCRIBERS`] readers). Not `Send`.
pub struct CameraViewer {
    subscriber: iceoryx2::port::subscriber::Subscriber<Ipc, [u16], FrameHeader>,
    _service: CameraService<Ipc>,
    _node: Node<Ipc>,
}

impl CameraViewer {
    /// Subscribes to `camera`, which a driver must be publishing on. `prefix` as
    /// [`crate::ClientOptions::prefix`] (`None`: `PPFD_PREFIX`, else iceoryx2's default).
    pub fn open(prefix: Option<&str>, camera: &str) -> Result<CameraViewer> {
        let node = node(prefix)?;
        let service = services::camera_builder(&node, camera)?
            .open()
            .map_err(|e| Error::Transport(format!("cannot open camera {camera:?}: {e:?}")))?;
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(transport("cannot subscribe to the camera"))?;
        Ok(CameraViewer {
            subscriber,
            _service: service,
            _node: node,
        })
    }

    /// The frames received since the last call, oldest first (at most
    /// [`limits::CAMERA_SUBSCRIBER_BUFFER`]: older ones are replaced), copied out.
    pub fn frames(&self) -> Result<Vec<(FrameHeader, Vec<u16>)>> {
        let mut out = Vec::new();
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(transport("cannot receive a frame"))?
        {
            out.push((*sample.user_header(), sample.payload().to_vec()));
        }
        Ok(out)
    }
}
