//! Control requests: the model listing, statistics, and model loads and drops, answered by the
//! I/O thread (a load runs on a thread of its own).

use ppfd_protocol::control::{ControlCommand, ControlResponseHeader, ModelInfo};
use ppfd_protocol::detect::Status;
use ppfd_protocol::services::limits;
use ppfd_protocol::text;

use crate::responder::ControlActive;

use super::Daemon;

impl Daemon {
    pub(super) fn take_control_requests(&mut self) {
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

    pub(super) fn control(&mut self, active: ControlActive) {
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
            // by a file of the folder with the same id. Clients that come and go faster than
            // housekeeping runs are let go of here too.
            if self.held_control.len() >= limits::MAX_CLIENTS {
                self.drop_dead_clients_held_control();
            }
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
                let m = self
                    .config
                    .detector_summary(ppfd_protocol::MESSAGE_BYTES - 1);
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
            ControlCommand::LoadModel => self.load_model(active, request),
        }
    }

    pub(super) fn control_answer(
        &mut self,
        active: ControlActive,
        status: Status,
        message: &str,
        models: &[ModelInfo],
    ) {
        // A refused load or drop is logged whole: the answer's message is cut to fit, and a
        // loading script's journal must say why.
        let command = active.payload().command;
        if status != Status::Ok
            && [ControlCommand::LoadModel, ControlCommand::DropModel]
                .iter()
                .any(|&c| c as u32 == command)
        {
            tracing::warn!(status = status.name(), "control request refused: {message}");
        }
        if !self.responder.control_client_alive(&active) {
            // As for detect requests: never touch a dead client's possibly reused channel.
            self.responder.abandon_control(active);
            return;
        }
        let mut stats = self.stats.snapshot();
        if active.payload().command == ControlCommand::Statistics as u32 {
            self.stats.add_recent(&mut stats);
        }
        stats.cameras = self.cameras.len() as u64;
        stats.models_loaded = self.registry.len() as u64;
        stats.model_bytes = self.registry.bytes();
        // Jobs handed to the pool wait there until a worker takes them.
        let running = self
            .in_flight
            .values()
            .filter(|j| j.started.load(std::sync::atomic::Ordering::Relaxed))
            .count();
        stats.in_flight = running as u64;
        stats.queued = (self.queue.len() + self.in_flight.len() - running) as u64;
        (
            stats.startup_files,
            stats.startup_files_done,
            stats.startup_files_failed,
        ) = match &self.startup {
            Some(loading) => loading.progress(),
            None => self.startup_files,
        };
        stats.model_loads_running = u64::from(self.loading.is_some());
        stats.model_loads_waiting = self.loads_waiting() as u64;
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
}
