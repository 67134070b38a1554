//! What a client's messages do: the token, IMAGE volumes, `ProbeTarget` transforms and GET_STATUS.

use super::codec;
use super::codec::{status_code, Body, Header, Transform};
use super::config::{MAX_IMAGE_VOXELS, PROBE_TARGET_DEVICE, TOKEN_METADATA_KEY};
use super::state::{Connection, Shared};
use super::stream::{status_of, MM_PER_M};
use crate::auth::token_matches;
use glam::DVec3;
use std::sync::atomic::{AtomicU16, Ordering};
use std::sync::Arc;
use tokio::sync::{mpsc, watch};
use voxhap_api::{ControlCommand, ControlError, SessionApi};

/// Applies the newest `ProbeTarget` of one client, one at a time, on the blocking pool.
pub(super) async fn apply_targets(
    shared: Arc<Shared>,
    mut targets: watch::Receiver<Option<DVec3>>,
    replies: mpsc::Sender<Reply>,
) {
    while targets.changed().await.is_ok() {
        let Some(target_m) = *targets.borrow_and_update() else {
            continue;
        };
        let api = shared.api.clone();
        let applied = tokio::task::spawn_blocking(move || {
            api.control(ControlCommand::SetHandTarget {
                position_m: Some(target_m.to_array()),
            })
        })
        .await;
        let failure = match applied {
            Ok(Ok(_)) => None,
            Ok(Err(error)) => Some(error.to_string()),
            Err(_) => Some("the request failed inside the server".to_owned()),
        };
        if let Some(message) = failure {
            let _ = replies
                .send(Reply::new(
                    PROBE_TARGET_DEVICE,
                    status_code::CONFIGURATION_ERROR,
                    "Refused",
                    message,
                ))
                .await;
        }
    }
}

/// The request side of one connection.
pub(super) struct ClientSession {
    pub(super) shared: Arc<Shared>,
    /// Holds whether this connection sent the token (the accept loop reads it when choosing whom to close).
    pub(super) connection: Arc<Connection>,
    pub(super) replies: mpsc::Sender<Reply>,
    pub(super) targets: watch::Sender<Option<DVec3>>,
    pub(super) version: Arc<AtomicU16>,
}

/// The connection is gone (the writer stopped).
pub(super) struct Gone;

pub(super) fn control_code(error: &ControlError) -> u16 {
    match error {
        ControlError::Invalid(_) => status_code::CONFIGURATION_ERROR,
        ControlError::NotFound(_) => status_code::NOT_FOUND,
        ControlError::Conflict(_) => status_code::BUSY,
        ControlError::Unavailable(_) => status_code::DEVICE_NOT_READY,
    }
}

impl ClientSession {
    pub(super) fn authorised(&self) -> bool {
        self.connection.authorised.load(Ordering::Relaxed)
    }

    /// Records whether `given` is the token; true when it is.
    pub(super) fn authorise(&self, given: &str) -> bool {
        let matches = token_matches(&self.shared.token, given);
        self.connection.authorised.store(matches, Ordering::Relaxed);
        matches
    }

    pub(super) async fn reply(&self, reply: Reply) -> bool {
        self.replies.send(reply).await.is_ok()
    }

    /// Answers one request; `Err` when the connection is gone.
    pub(super) async fn handle(&mut self, header: Header, raw: Vec<u8>) -> Result<(), Gone> {
        let device = header.device_name.clone();
        let sent = |ok: bool| if ok { Ok(()) } else { Err(Gone) };
        if let Err(error) = header.check_crc(&raw) {
            let reply = Reply::new(
                &device,
                status_code::CHECKSUM_ERROR,
                "ChecksumError",
                format!("{} {device:?} dropped: {error}", header.type_name),
            );
            return sent(self.reply(reply).await);
        }
        // The client speaks this header version: answer and stream in it from now on.
        self.version.store(header.version, Ordering::Relaxed);
        let body = match Body::split(header.version, &raw) {
            Ok(body) => body,
            Err(error) => {
                let message = format!("{} {device:?}: {error}", header.type_name);
                return sent(
                    self.reply(Reply::configuration_error(&device, message))
                        .await,
                );
            }
        };
        if let Some(token) = body.metadata_value(TOKEN_METADATA_KEY) {
            self.authorise(token);
        }
        match header.type_name.as_str() {
            "STRING" => {
                let reply = match codec::decode_string(body.content) {
                    Ok(text) => self.string(&device, &text),
                    Err(error) => Reply::configuration_error(&device, error.to_string()),
                };
                sent(self.reply(reply).await)
            }
            "TRANSFORM" if device == PROBE_TARGET_DEVICE => {
                if !self.authorised() {
                    return sent(self.reply(self.denied(&device, "ProbeTarget")).await);
                }
                match Transform::decode(body.content) {
                    Ok(transform) => {
                        let _ = self.targets.send(Some(transform.translation / MM_PER_M));
                        Ok(())
                    }
                    Err(error) => sent(
                        self.reply(Reply::configuration_error(&device, error.to_string()))
                            .await,
                    ),
                }
            }
            "IMAGE" => {
                if !self.authorised() {
                    return sent(self.reply(self.denied(&device, "IMAGE")).await);
                }
                let volume = body.metadata_value("volume").map(str::to_owned);
                // The body moves into the blocking task (decode and write happen there), never copied.
                let start = body.content.as_ptr() as usize - raw.as_ptr() as usize;
                let content = start..start + body.content.len();
                drop(body);
                let reply = self.image(&device, raw, content, volume).await;
                sent(self.reply(reply).await)
            }
            "GET_STATUS" => {
                let (code, name, message) = status_of(self.shared.api.snapshot().as_ref());
                sent(self.reply(Reply::new(&device, code, name, message)).await)
            }
            // TRANSFORMs of other names (Slicer may echo nodes back), STATUS, and other types: ignored.
            _ => Ok(()),
        }
    }

    pub(super) fn denied(&self, device: &str, what: &str) -> Reply {
        Reply::new(
            device,
            status_code::ACCESS_DENIED,
            "AccessDenied",
            format!(
                "{what} needs the control token: send the STRING \"token <T>\" first, or the metadata entry \
                 \"{TOKEN_METADATA_KEY}\" (T is printed by voxhap serve as 'igtl: control token T')"
            ),
        )
    }

    pub(super) fn string(&mut self, device: &str, text: &str) -> Reply {
        let text = text.trim();
        match text.split_once(' ') {
            Some(("token", given)) => {
                if self.authorise(given.trim()) {
                    Reply::new(
                        device,
                        status_code::OK,
                        "OK",
                        "token accepted: this connection may load volumes and move the hand",
                    )
                } else {
                    Reply::new(
                        device,
                        status_code::ACCESS_DENIED,
                        "AccessDenied",
                        "wrong token",
                    )
                }
            }
            _ => Reply::new(
                device,
                status_code::UNKNOWN_INSTRUCTION,
                "UnknownCommand",
                format!(
                    "unknown STRING command {:?}; voxhap understands \"token <T>\"",
                    text.chars().take(40).collect::<String>()
                ),
            ),
        }
    }

    /// Decodes, writes and loads an IMAGE; the STATUS that answers it.
    pub(super) async fn image(
        &self,
        device: &str,
        raw: Vec<u8>,
        content: std::ops::Range<usize>,
        volume: Option<String>,
    ) -> Reply {
        let Ok(_permit) = self.shared.images.acquire().await else {
            return Reply::new(
                device,
                status_code::DEVICE_NOT_READY,
                "Error",
                "the server is stopping",
            );
        };
        let shared = self.shared.clone();
        let device_name = device.to_owned();
        let loaded = tokio::task::spawn_blocking(move || -> Result<String, (u16, String)> {
            let image = codec::decode_image(&raw[content], MAX_IMAGE_VOXELS)
                .map_err(|e| (status_code::CONFIGURATION_ERROR, e.to_string()))?;
            drop(raw);
            let path = {
                let mut folder = shared.folder.lock().map_err(|_| {
                    (status_code::UNKNOWN_ERROR, "the image folder is unavailable".to_owned())
                })?;
                let folder = folder.as_mut().ok_or((
                    status_code::DEVICE_NOT_READY,
                    "the server is stopping".to_owned(),
                ))?;
                folder
                    .write(&device_name, &image)
                    .map_err(|e| (status_code::NOT_ENOUGH_RESOURCE, e.to_string()))?
            };
            let dims = image.dims;
            let (lo, hi) = image
                .values
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
            drop(image);
            let replaced = volume.clone();
            let reply = shared
                .api
                .control(ControlCommand::LoadVolume { path, name: volume })
                .map_err(|e| (control_code(&e), e.to_string()))?;
            shared.counters.images_loaded.fetch_add(1, Ordering::Relaxed);
            let refits = refit_surfaces(shared.api.as_ref(), replaced.as_deref(), lo, hi);
            Ok(format!(
                "volume {device_name:?} loaded: {} x {} x {} voxels, values {lo} to {hi}; scene generation {}{refits}",
                dims[0], dims[1], dims[2], reply.scene_generation
            ))
        })
        .await;
        match loaded {
            Ok(Ok(message)) => Reply::new(device, status_code::OK, "OK", message),
            Ok(Err((code, message))) => {
                Reply::new(device, code, "Error", format!("IMAGE refused: {message}"))
            }
            Err(_) => Reply::new(
                device,
                status_code::UNKNOWN_ERROR,
                "Error",
                "the IMAGE failed inside the server",
            ),
        }
    }
}

/// After an IMAGE replaced the volume `replaced` (default: the first), a surface mode on it whose surface
/// the new values cannot show (the value where its transfer reaches half strength lies outside `lo ..= hi`)
/// gets a transfer fitted to the image, as `voxhap serve --volume` does for a lone volume: 0 N at 45 % of
/// the range, the mode's largest strength at 50 %. Returns what was changed, for the STATUS text.
pub(super) fn refit_surfaces(
    api: &dyn SessionApi,
    replaced: Option<&str>,
    lo: f32,
    hi: f32,
) -> String {
    use voxhap_core::haptics::modes::{ModeKind, TransferFunction};
    use voxhap_view::volume::half_strength_value;
    let scene = api.scene();
    let Some(name) = replaced.or_else(|| scene.volumes.first().map(|v| v.name.as_str())) else {
        return String::new();
    };
    let (lo, hi) = (f64::from(lo), f64::from(hi));
    if hi <= lo {
        return String::new();
    }
    let mut changed = String::new();
    for mode in &scene.modes {
        let Some(transfer) = mode.transfer.as_ref() else {
            continue;
        };
        if mode.kind != ModeKind::Surface || mode.volume.as_deref() != Some(name) {
            continue;
        }
        let fits = half_strength_value(transfer).is_some_and(|iso| lo < iso && iso < hi);
        if fits {
            continue;
        }
        let span = hi - lo;
        let Ok(fitted) = TransferFunction::new(vec![
            [lo + 0.45 * span, 0.0],
            [lo + 0.5 * span, transfer.max_strength_n().max(1e-3)],
        ]) else {
            continue;
        };
        let points = fitted.points().to_vec();
        let mode_name = mode.display_name().to_owned();
        if api
            .control(ControlCommand::SetTransfer {
                mode: mode_name.clone(),
                transfer: fitted,
            })
            .is_ok()
        {
            changed.push_str(&format!(
                "; the transfer of surface mode {mode_name:?} did not fit these values and is now {points:?}"
            ));
        }
    }
    changed
}

/// A reply the reader asks the writer to send: STATUS content for `device`.
pub(super) struct Reply {
    pub(super) device: String,
    pub(super) code: u16,
    pub(super) error_name: &'static str,
    pub(super) message: String,
}

impl Reply {
    /// A `CONFIGURATION_ERROR` ("Error") reply: the request could not be read or used.
    pub(super) fn configuration_error(device: &str, message: impl Into<String>) -> Self {
        Reply::new(device, status_code::CONFIGURATION_ERROR, "Error", message)
    }

    pub(super) fn new(
        device: &str,
        code: u16,
        error_name: &'static str,
        message: impl Into<String>,
    ) -> Self {
        Reply {
            device: device.to_owned(),
            code,
            error_name,
            message: message.into(),
        }
    }
}
