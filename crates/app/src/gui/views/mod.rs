//! The views, each one function that allocates its rect, draws its image, hit-tests the pointer and acts on the
//! window through [`super::Command`]s and the interaction state: [`slices`] (the three slice views with their
//! positions and oblique controls) and [`view3d`] (the 3-D view).

pub mod slices;
pub mod view3d;
