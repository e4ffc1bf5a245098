//! The cameras the daemon subscribes to: opened when the housekeeper finds them or a request
//! names them, each keeping its newest frame, and forgotten once no driver has published on
//! them for `forget_camera_after_ms`.

use std::rc::Rc;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use ppfd_protocol::detect::Status;
use ppfd_protocol::services::{self, CameraService};

use crate::engine::EngineError;
use crate::responder::Ipc;

use super::{Daemon, FrameSample, FrameSubscriber};

/// A camera the daemon subscribes to, and its newest frame.
pub(super) struct Camera {
    pub(super) newest: Option<Rc<FrameSample>>,
    subscriber: FrameSubscriber,
    service: CameraService<Ipc>,
    /// Since when no driver publishes on it (counted at housekeeping rounds).
    driverless_since: Option<Instant>,
}

impl Camera {
    /// Whether a driver publishes on the camera now.
    pub(super) fn has_driver(&self) -> bool {
        self.service.dynamic_config().number_of_publishers() > 0
    }

    /// Whether the camera has been without a driver for `limit`, as of `now`; keeps count.
    fn driverless_for(&mut self, limit: Duration, now: Instant) -> bool {
        if self.has_driver() {
            self.driverless_since = None;
            return false;
        }
        let since = *self.driverless_since.get_or_insert(now);
        now.saturating_duration_since(since) >= limit
    }

    /// Takes every waiting frame, keeping the newest. Returns how many arrived.
    pub(super) fn refresh(&mut self, name: &str) -> u64 {
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

impl Daemon {
    /// Subscribes to the cameras the housekeeper found. One that cannot be subscribed to now
    /// (no driver publishes on it yet, or any more) is reported again at the next scan.
    pub(super) fn open_found_cameras(&mut self) {
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
    pub(super) fn forget_driverless_cameras(&mut self) {
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

    pub(super) fn open_camera(&mut self, name: &str) -> Result<&mut Camera, EngineError> {
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
}
