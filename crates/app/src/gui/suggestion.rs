//! Suggested targets in the window (issue 18, item 2): when the source of a new pair is placed, the fixed point the
//! current warp predicts for it, refined by the local similarity search of [`warpbench_solver::suggest`], is shown
//! as a ghost glyph; Enter takes it as the pair's target, a press on the ghost takes it and drags its fixed point, Esc
//! drops it (then a click places the target by hand), and *Refine pair* runs the search again for a pair that exists
//! (its fixed point moves to the suggestion, one undo step). The images the search reads are made from the loaded
//! volumes once, on the first suggestion, and again after a volume is replaced.

use warpbench_io::Volume;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_solver::image::Image;
use warpbench_solver::spaces::{Fixed, Moving, as_moving};
use warpbench_solver::suggest::{SuggestParams, suggest};
use warpbench_solver::warp::Parallelism;
use warpbench_solver::warp::Warp;

/// A suggested target: the fixed point (LPS mm) and how sure the search is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Suggested {
    pub fixed_lps: [f64; 3],
    /// The warp's prediction the search started from.
    pub predicted_lps: [f64; 3],
    /// In [0, 1] ([`warpbench_solver::suggest`]).
    pub confidence: f64,
    pub low_confidence: bool,
}

/// The ghost glyph's colour: a pale green, apart from the pairs' blue and orange.
pub const GHOST_COLOUR: [f32; 4] = [0.55, 1.0, 0.55, 0.9];

/// The same, for a suggestion of low confidence: amber.
pub const GHOST_LOW_COLOUR: [f32; 4] = [1.0, 0.75, 0.25, 0.9];

/// The images the search reads, made from the loaded volumes when first needed.
#[derive(Debug, Default)]
pub struct Matching {
    images: Option<(Image<Fixed>, Image<Moving>)>,
}

impl Matching {
    /// Forgets the images (a volume was replaced).
    pub fn reset(&mut self) {
        self.images = None;
    }

    /// The suggested fixed point of moving point `p`, predicted by `fixed_from_moving` (the current warp's forward
    /// map). Errors are the window's sentences.
    ///
    /// # Errors
    /// An image that cannot be made, or a search that fails (the patch leaves a volume, a flat patch).
    pub fn suggest(
        &mut self,
        (fixed, moving): (&Volume, &Volume),
        fixed_from_moving: &dyn Warp<Fixed, Moving>,
        p: Point3<Lps>,
    ) -> Result<Suggested, String> {
        if self.images.is_none() {
            let f = Image::<Fixed>::from_volume(fixed, Parallelism::Rayon)
                .map_err(|e| format!("no suggestion: the fixed volume: {e}"))?;
            let m = Image::<Moving>::from_volume(moving, Parallelism::Rayon)
                .map_err(|e| format!("no suggestion: the moving volume: {e}"))?;
            self.images = Some((f, m));
        }
        let Some((f, m)) = &self.images else { return Err("no suggestion: no images".into()) };
        let s = suggest(m, f, fixed_from_moving, as_moving(p), &SuggestParams::default())
            .map_err(|e| format!("no suggestion: {e}"))?;
        Ok(Suggested {
            fixed_lps: s.fixed.coords(),
            predicted_lps: s.predicted.coords(),
            confidence: s.confidence,
            low_confidence: s.low_confidence,
        })
    }
}
