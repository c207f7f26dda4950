//! The choices a user makes by name: how the two volumes blend ([`Blend`]), the warp family ([`MethodKind`]), how a
//! click in the 3-D view finds its point ([`Probe`]), the lighting ([`Shading`]), a volume's transfer function
//! ([`Preset`]), the procedural deformation of the moving volume ([`ProceduralKind`]) and what a registration by
//! intensities matches ([`Metric`]).
//!
//! Each is an enum with `ALL` (menu order), `name()` (the stable name sessions store and the command line takes),
//! `FromStr` and `Display` by that name, serde as that name, and `clap::ValueEnum`, so that the window, the session
//! files and the command line spell every choice one way. A choice's parameters (the mix weight, the TPS stiffness,
//! the probe's threshold) are separate numbers beside it: a menu switches the kind and keeps the numbers.

use std::fmt;
use std::str::FromStr;

use warpbench_solver::bspline::BSplineParams;
use warpbench_solver::linear::LinearKind;
use warpbench_solver::method::Method;
use warpbench_solver::register::Similarity;

/// A name that is none of a choice's names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownChoice {
    /// What was being chosen, e.g. "blend mode".
    pub what: &'static str,
    pub given: String,
    /// The names it accepts, in menu order.
    pub names: Vec<&'static str>,
}

impl fmt::Display for UnknownChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown {} {:?}; use one of {}", self.what, self.given, self.names.join(", "))
    }
}

impl std::error::Error for UnknownChoice {}

/// Defines a choice enum: its variants with their names, `ALL`, `name()`, `FromStr`, `Display`, serde by name and
/// `clap::ValueEnum`.
macro_rules! choice {
    (
        $(#[$meta:meta])*
        $name:ident, $what:literal, default $default:ident {
            $($(#[$vmeta:meta])* $variant:ident = $text:literal,)+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum $name {
            $($(#[$vmeta])* $variant,)+
        }

        impl $name {
            /// Every choice, in menu order.
            pub const ALL: &'static [Self] = &[$(Self::$variant),+];

            /// The stable name: what sessions store, menus show and the command line takes.
            #[must_use]
            pub fn name(self) -> &'static str {
                match self {
                    $(Self::$variant => $text,)+
                }
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Self::$default
            }
        }

        impl FromStr for $name {
            type Err = UnknownChoice;

            fn from_str(s: &str) -> Result<Self, Self::Err> {
                Self::ALL.iter().copied().find(|c| c.name() == s).ok_or_else(|| UnknownChoice {
                    what: $what,
                    given: s.to_owned(),
                    names: Self::ALL.iter().map(|c| c.name()).collect(),
                })
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.name())
            }
        }

        impl serde::Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }

        impl<'de> serde::Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let name = String::deserialize(d)?;
                name.parse().map_err(serde::de::Error::custom)
            }
        }

        impl clap::ValueEnum for $name {
            fn value_variants<'a>() -> &'a [Self] {
                Self::ALL
            }

            fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
                Some(clap::builder::PossibleValue::new(self.name()))
            }
        }
    };
}

choice! {
    /// How the fixed and the deformed moving volume combine in a frame ([`warpbench_gpu::BlendMode`]).
    Blend, "blend mode", default Mix {
        /// (1 − w)·fixed + w·moving.
        Mix = "mix",
        Additive = "additive",
        Difference = "difference",
        /// Cells of a 3-D checkerboard alternate between the volumes.
        Checkerboard = "checkerboard",
        RedCyan = "red-cyan",
        FixedOnly = "fixed-only",
        MovingOnly = "moving-only",
    }
}

impl Blend {
    /// The renderer's blend with this kind's parameter: the moving weight of a mix, the cell of a checkerboard.
    #[must_use]
    pub fn mode(self, mix_weight: f32, checker_mm: f32) -> warpbench_gpu::BlendMode {
        use warpbench_gpu::BlendMode as B;
        match self {
            Self::Mix => B::Mix { moving_weight: mix_weight },
            Self::Additive => B::Additive,
            Self::Difference => B::Difference,
            Self::Checkerboard => B::Checkerboard { cell_mm: checker_mm },
            Self::RedCyan => B::RedCyan,
            Self::FixedOnly => B::FixedOnly,
            Self::MovingOnly => B::MovingOnly,
        }
    }
}

choice! {
    /// The warp family fitted to the pairs ([`Method`]).
    MethodKind, "warp method", default Tps {
        /// Thin-plate spline, interpolating or smoothed by its stiffness.
        Tps = "tps",
        /// Hierarchical (multilevel) B-spline.
        BSpline = "hbspline",
        Affine = "affine",
        Similarity = "similarity",
        Rigid = "rigid",
    }
}

/// `--stiffness`: the TPS's λ (≥ 0; 0 interpolates), or `auto`, the λ under which the pairs are most likely
/// ([`warpbench_solver::stiffness`]), chosen once the pairs are read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stiffness {
    Value(f64),
    Auto,
}

impl Default for Stiffness {
    fn default() -> Self {
        Self::Value(0.0)
    }
}

impl fmt::Display for Stiffness {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Value(v) => write!(f, "{v}"),
            Self::Auto => write!(f, "auto"),
        }
    }
}

impl FromStr for Stiffness {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok(Self::Auto);
        }
        match s.trim().parse::<f64>() {
            Ok(v) if v.is_finite() && v >= 0.0 => Ok(Self::Value(v)),
            _ => Err(format!("{s:?} is not a stiffness: give a number ≥ 0, or auto")),
        }
    }
}

impl MethodKind {
    /// The method of this kind with its parameters: the TPS stiffness (λ), the B-spline's levels.
    #[must_use]
    pub fn method(self, stiffness: f64, bspline_levels: usize) -> Method {
        match self {
            Self::Tps => Method::Tps { stiffness },
            Self::BSpline => Method::BSpline(BSplineParams { levels: bspline_levels, ..BSplineParams::default() }),
            Self::Affine => Method::Linear(LinearKind::Affine),
            Self::Similarity => Method::Linear(LinearKind::Similarity),
            Self::Rigid => Method::Linear(LinearKind::Rigid),
        }
    }
}

choice! {
    /// What a registration by intensities matches the volumes by ([`Similarity`]): `warpbench register --metric` and
    /// the window's Refine by intensities.
    Metric, "similarity measure", default Mi {
        /// Mattes mutual information: any two modalities (MR–CT, T1–T2).
        Mi = "mi",
        /// Normalised gradient fields: the edges, whatever their contrast.
        Ngf = "ngf",
        /// Local normalised cross-correlation: one modality whose brightness varies across the volume.
        Lncc = "lncc",
    }
}

impl From<Similarity> for Metric {
    /// The choice that is the solver's measure: [`Metric::similarity`] undone.
    fn from(similarity: Similarity) -> Self {
        match similarity {
            Similarity::Mi => Self::Mi,
            Similarity::Ngf => Self::Ngf,
            Similarity::Lncc => Self::Lncc,
        }
    }
}

impl Metric {
    /// The solver's measure.
    #[must_use]
    pub fn similarity(self) -> Similarity {
        match self {
            Self::Mi => Similarity::Mi,
            Self::Ngf => Similarity::Ngf,
            Self::Lncc => Similarity::Lncc,
        }
    }

    /// What a menu shows.
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Mi => "Mutual information",
            Self::Ngf => "Edges (NGF)",
            Self::Lncc => "Local correlation",
        }
    }

    /// When to choose it, for a menu's hover text.
    #[must_use]
    pub fn hint(self) -> &'static str {
        match self {
            Self::Mi => "Any two modalities: an MRI to a CT, a T1 to a T2",
            Self::Ngf => "The outlines (normalised gradient fields), whatever their contrast",
            Self::Lncc => "One modality whose brightness varies across the volume (different coils, a bias field)",
        }
    }

    /// What a summary calls the measure's value.
    #[must_use]
    pub fn measure(self) -> &'static str {
        match self {
            Self::Mi => "mutual information",
            Self::Ngf => "edge alignment",
            Self::Lncc => "local correlation",
        }
    }
}

choice! {
    /// What a click in the 3-D view counts as the surface it hits ([`warpbench_gpu::Probe`]).
    Probe, "pick probe", default Accumulated {
        /// Where the accumulated opacity reaches the threshold.
        Accumulated = "accumulated opacity",
        /// The first sample whose opacity reaches the threshold.
        Opacity = "opacity",
        /// The first sample whose gradient magnitude (value units per mm) reaches the threshold.
        Gradient = "gradient",
    }
}

impl Probe {
    /// The picking pass's probe with `threshold`.
    #[must_use]
    pub fn with_threshold(self, threshold: f32) -> warpbench_gpu::Probe {
        use warpbench_gpu::Probe as P;
        match self {
            Self::Accumulated => P::Accumulated { level: threshold },
            Self::Opacity => P::Opacity { threshold },
            Self::Gradient => P::Gradient { threshold },
        }
    }

    /// The threshold a switch to this probe starts from.
    #[must_use]
    pub fn default_threshold(self) -> f32 {
        match self {
            Self::Accumulated => 0.95,
            Self::Opacity => 0.5,
            Self::Gradient => 50.0,
        }
    }

    /// The range the threshold's slider offers.
    #[must_use]
    pub fn threshold_range(self) -> std::ops::RangeInclusive<f32> {
        match self {
            Self::Gradient => 0.0..=2000.0,
            Self::Accumulated | Self::Opacity => 0.0..=1.0,
        }
    }
}

choice! {
    /// How the views share the window.
    Layout, "layout", default FourUp {
        /// The 3-D view and the three slices in equal panes.
        FourUp = "four-up",
        /// The 3-D view alone.
        ThreeD = "3-d",
        /// The three slices side by side.
        Slices = "slices",
        /// The fixed volume and the warped moving volume side by side in the same axial plane, linked (as BigWarp's
        /// two viewers).
        SideBySide = "side by side",
    }
}

choice! {
    /// What the slices draw over the images to show the warp itself.
    Overlay, "warp overlay", default None {
        None = "none",
        /// det ∇u: diverging colours around 1, folding (det ≤ 0) in a colour of its own.
        Jacobian = "jacobian",
        /// |u(x) − x|, mm.
        Displacement = "displacement",
        /// The slice's grid moved by the warp's displacement within the plane.
        Grid = "grid",
    }
}

choice! {
    /// How samples are lit ([`warpbench_gpu::ShadingMode`]).
    Shading, "shading", default Dvr {
        /// The transfer function's colour as it is.
        None = "none",
        /// Direct volume rendering, lit by the gradient.
        Dvr = "dvr",
        /// Each volume's first surface above its iso value, lit and opaque.
        Iso = "iso",
    }
}

impl Shading {
    #[must_use]
    pub fn mode(self) -> warpbench_gpu::ShadingMode {
        use warpbench_gpu::ShadingMode as S;
        match self {
            Self::None => S::None,
            Self::Dvr => S::Dvr,
            Self::Iso => S::Iso,
        }
    }
}

choice! {
    /// A deformation of the moving volume the renderer computes per sample ([`crate::procedural`]); the closed-form
    /// synthetic warps of `eval` and a shift.
    ProceduralKind, "procedural deformation", default Sine {
        /// A constant offset.
        Shift = "shift",
        /// A shear of sines, one wavelength across the volume.
        Sine = "sine",
        /// A rotation about an axis by an angle growing along it.
        Twist = "twist",
        /// The axis bent into an arc.
        Bend = "bend",
        /// A Gaussian bump.
        Bump = "bump",
    }
}

choice! {
    /// A volume's transfer function ([`warpbench_gpu::Preset`]).
    Preset, "preset", default GreyRamp {
        CtBone = "ct-bone",
        CtSoftTissue = "ct-soft-tissue",
        MrT1 = "mr-t1",
        GreyRamp = "grey-ramp",
    }
}

impl Preset {
    /// The renderer's preset.
    #[must_use]
    pub fn gpu(self) -> warpbench_gpu::Preset {
        use warpbench_gpu::Preset as P;
        match self {
            Self::CtBone => P::CtBone,
            Self::CtSoftTissue => P::CtSoftTissue,
            Self::MrT1 => P::MrT1,
            Self::GreyRamp => P::GreyRamp,
        }
    }

    /// The choice for the renderer's preset `p` (what [`crate::scene::auto_style`] picks).
    #[must_use]
    pub fn of(p: warpbench_gpu::Preset) -> Self {
        use warpbench_gpu::Preset as P;
        match p {
            P::CtBone => Self::CtBone,
            P::CtSoftTissue => Self::CtSoftTissue,
            P::MrT1 => Self::MrT1,
            P::GreyRamp => Self::GreyRamp,
        }
    }
}

/// Deserializes a choice leniently: a name this version does not know (a file from a newer one) gives the
/// default, as a menu without that entry would show.
pub fn or_default<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: serde::Deserializer<'de>,
    T: FromStr + Default,
{
    use serde::Deserialize as _;
    let name = String::deserialize(d)?;
    Ok(name.parse().unwrap_or_default())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every choice's names are distinct, parse back to it, and serialize as the bare name.
    fn laws<T>(all: &[T])
    where
        T: Copy + PartialEq + fmt::Debug + fmt::Display + FromStr<Err = UnknownChoice> + serde::Serialize,
    {
        for (i, &c) in all.iter().enumerate() {
            let name = c.to_string();
            assert_eq!(name.parse::<T>(), Ok(c));
            assert_eq!(serde_json::to_value(c).expect("json"), serde_json::Value::String(name.clone()));
            assert!(all[..i].iter().all(|o| o.to_string() != name), "{name} twice");
        }
        let e = "no-such".parse::<T>().expect_err("unknown");
        assert_eq!(e.names.len(), all.len());
        assert!(e.to_string().contains("\"no-such\""), "{e}");
    }

    #[test]
    fn names_round_trip_and_unknown_names_list_the_choices() {
        laws(Blend::ALL);
        laws(MethodKind::ALL);
        laws(Probe::ALL);
        laws(Shading::ALL);
        laws(Preset::ALL);
        laws(Metric::ALL);
    }

    #[test]
    fn the_choices_name_what_the_renderer_and_the_solver_name() {
        for (&b, gpu) in Blend::ALL.iter().zip(warpbench_gpu::BlendMode::ALL) {
            assert_eq!(b.name(), gpu.name());
            assert_eq!(b.mode(0.5, 12.0), gpu);
        }
        for (&s, gpu) in Shading::ALL.iter().zip(warpbench_gpu::ShadingMode::ALL) {
            assert_eq!((s.name(), s.mode()), (gpu.name(), gpu));
        }
        for (&p, gpu) in Preset::ALL.iter().zip(warpbench_gpu::Preset::ALL) {
            assert_eq!((p.gpu(), Preset::of(gpu)), (gpu, p));
        }
        for &m in MethodKind::ALL {
            let method = m.method(0.0, BSplineParams::default().levels);
            // The solver's own names give the same method (their defaults: no stiffness, the default levels).
            assert_eq!(Method::from_name(m.name()).map(|x| x.to_string()), Some(method.to_string()));
        }
        assert_eq!(Probe::Opacity.with_threshold(0.25), warpbench_gpu::Probe::Opacity { threshold: 0.25 });
        for &m in Metric::ALL {
            // The solver's name of the measure, which `register --json` reports.
            assert_eq!(m.name(), m.similarity().to_string());
            assert_eq!(Metric::from(m.similarity()), m);
        }
    }

    #[test]
    fn an_unknown_name_in_a_file_reads_as_the_default() {
        #[derive(serde::Deserialize)]
        struct F {
            #[serde(deserialize_with = "or_default")]
            blend: Blend,
        }
        let f: F = serde_json::from_str(r#"{"blend": "hologram"}"#).expect("lenient");
        assert_eq!(f.blend, Blend::Mix);
        let f: F = serde_json::from_str(r#"{"blend": "red-cyan"}"#).expect("known");
        assert_eq!(f.blend, Blend::RedCyan);
    }
}
