//! The samples of a mutual-information or local-correlation level read on another device (a GPU), instead of the
//! CPU's threads.
//!
//! Per evaluation the work that grows with the samples is two passes: the moving image's value at every displaced
//! sample x + D(x), and, once the similarity has given each sample its weight w_s (the histogram's, or the patch
//! correlation's derivative), the gradient gathered per control point, Σ_s w_s B_k(x_s) ∇m'(x_s + D(x_s)). A
//! [`SampleDevice`] does those two; the histogram or the patches' sums, the weights, the bending and landmark terms
//! and the optimiser stay here, so both paths share every formula but the two passes. [`register_on`](super::register_on) takes the device; normalised gradient fields
//! always run on the CPU.
//!
//! A device computes in its own precision (a GPU in f32), so its result is not the CPU's bit for bit; it is
//! reproducible on the same device when the device's passes are (the GPU's gather uses no atomics).

use crate::image::Image;
use crate::spaces::Fixed;

/// One fixed sample as a device reads it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviceSample {
    /// The continuous index of the sample in [`DeviceLevel::image`].
    pub index: [f64; 3],
    /// The first of the 4 × 4 × 4 control points whose basis functions cover the sample.
    pub first: [usize; 3],
    /// The cubic B-spline weights along each axis there.
    pub weights: [[f64; 4]; 3],
}

/// One resolution level as a device needs it.
#[derive(Clone, Copy, Debug)]
pub struct DeviceLevel<'a> {
    /// The moving image pulled back by the start onto the level's fixed grid (NaN where it has no value).
    pub image: &'a Image<Fixed>,
    /// Control points per axis (x fastest; 3 coefficients each, x y z).
    pub lattice_dims: [usize; 3],
    pub samples: &'a [DeviceSample],
}

/// A device that reads registration samples ([`DeviceLevel`]s).
pub trait SampleDevice: Sync {
    /// What it is, for reports (e.g. the GPU adapter's name).
    fn describe(&self) -> String;

    /// Uploads one level.
    ///
    /// # Errors
    /// The device's message when it cannot hold or run the level.
    fn prepare<'d>(&'d self, level: &DeviceLevel<'_>) -> Result<Box<dyn DeviceSamples + 'd>, String>;
}

/// One level on a device.
pub trait DeviceSamples: Send + Sync {
    /// m'(x_s + D(x_s)) for every sample, in the order given (NaN outside the image), at the coefficients `phi`.
    ///
    /// # Errors
    /// The device's message.
    fn values(&self, phi: &[f64], out: &mut [f64]) -> Result<(), String>;

    /// Σ_s w_s B_k(x_s) ∇m'(x_s + D(x_s)) for every coefficient (3 per control point), at the coefficients of the
    /// last [`Self::values`]; a sample of weight 0 adds nothing.
    ///
    /// # Errors
    /// The device's message.
    fn weighted_gradient(&self, weights: &[f64], out: &mut [f64]) -> Result<(), String>;
}
