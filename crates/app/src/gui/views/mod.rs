//! The views, each one function that allocates its rect, draws its image, hit-tests the pointer and acts on the
//! window through [`super::Command`]s and the interaction state: [`slices`] (a slice view with its position and
//! oblique controls) and [`view3d`] (the 3-D view), laid out in the panes of [`panes`].

pub mod panes;
pub mod slices;
pub mod view3d;
