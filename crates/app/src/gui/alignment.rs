//! Auto-align in the window (issue 18, item 1): the automatic alignment of `warpbench align`
//! ([`warpbench_solver::align`]) run on a thread of its own on the pair as loaded, whose result becomes the document's
//! starting transform ([`crate::project::document::StartingTransform`], one undo step) under the landmark warp.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, TryRecvError};

use warpbench_io::Volume;
use warpbench_solver::align::{AlignKind, AlignParams, align, rotation_angle_deg};
use warpbench_solver::image::Image;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Parallelism;

use crate::project::document::StartingTransform;

/// An alignment being computed.
#[derive(Debug)]
pub struct AlignJob {
    done: Receiver<Result<StartingTransform, String>>,
}

/// The alignment of `moving` to `fixed` as the document keeps it, named by what it found.
///
/// # Errors
/// The solver's, in the window's words.
pub fn align_pair(fixed: &Volume, moving: &Volume, kind: AlignKind) -> Result<StartingTransform, String> {
    let fixed = Image::<Fixed>::from_volume(fixed, Parallelism::Rayon)
        .map_err(|e| format!("Auto-align: the fixed volume: {e}"))?;
    let moving = Image::<Moving>::from_volume(moving, Parallelism::Rayon)
        .map_err(|e| format!("Auto-align: the moving volume: {e}"))?;
    let result = align(&fixed, &moving, &AlignParams { kind, ..AlignParams::default() })
        .map_err(|e| format!("Auto-align: {e}"))?;
    let t = result.moving_from_fixed;
    let origin =
        format!("Auto-align ({kind}, {:.1} deg, MI {:.3})", rotation_angle_deg(&t.linear()), result.mutual_information);
    Ok(StartingTransform::new(t.linear(), t.translation(), origin))
}

impl AlignJob {
    /// Starts aligning `moving` to `fixed` on a new thread, which calls `wake` when it is done.
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn start(
        fixed: Arc<Volume>,
        moving: Arc<Volume>,
        kind: AlignKind,
        wake: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<Self> {
        let (send, done) = std::sync::mpsc::channel();
        std::thread::Builder::new().name("auto-align".into()).spawn(move || {
            // The receiver is gone when the pair was replaced meanwhile: nothing to hand back.
            if send.send(align_pair(&fixed, &moving, kind)).is_ok() {
                wake();
            }
        })?;
        Ok(Self { done })
    }

    /// The result once it is there; an error when the thread ended without one (it panicked).
    #[must_use]
    pub fn poll(&self) -> Option<Result<StartingTransform, String>> {
        match self.done.try_recv() {
            Ok(result) => Some(result),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err("Auto-align stopped (a bug): try again".into())),
        }
    }
}
