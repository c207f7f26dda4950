//! The warp stack: the ordered layers that make the pull-back u = `moving_from_fixed`, and its forward map d =
//! `fixed_from_moving`.
//!
//! A registration is, from the moving volume's side to the fixed volume's:
//!
//! 1. a **starting transform** T₀, affine (`warpbench align`, Auto-align, `--initial`; [`crate::start`]);
//! 2. a **displacement field** F, read from a file of another tool (ITK, ANTs or Slicer flavour;
//!    [`FieldLayer`]): F(x) = x + D(x), zero displacement outside its grid, as ITK maps points;
//! 3. the **landmark fit**, r for the pull-back and s for the forward map, in the method's family (TPS,
//!    hierarchical B-spline, linear), fitted on the pairs *after* the layers under it have acted;
//! 4. the **brush** b, a forward warp of the fixed space ([`crate::brushed`]).
//!
//! With pairs (pᵢ moving, qᵢ fixed) and the base B = T₀ ∘ F (either may be absent, then it is the identity):
//!
//! - u = B ∘ r ∘ b⁻¹, r fitted on qᵢ → B⁻¹(pᵢ) over the fixed box, so u(qᵢ) = pᵢ where b is the identity;
//! - d = b ∘ F⁻¹ ∘ T₀⁻¹ ∘ s, s fitted on pᵢ → B(qᵢ) over the moving box, so d(pᵢ) = qᵢ likewise.
//!
//! Without a field this is the composition [`crate::start`] has always made (r and s followed by T₀ and T₀⁻¹ fold
//! into one warp of the method's family, which the GPU, the exporters and the ITK transform file take as any fit).
//! F⁻¹ is evaluated point by point ([`PointInverse`]). With fewer pairs than the method needs and a base, the base
//! alone is the warp; without a base that is an error.
//!
//! [`StackPullback`] and [`StackForward`] (both: [`FittedStack`]) are the one evaluation of each direction, and the
//! pull-back gives the one control texture ([`StackPullback::control_texture`]) and the one ITK transform
//! ([`StackPullback::itk_transform`]).

use std::path::Path;
use std::sync::Arc;

use anyhow::anyhow;
use warpbench_io::displacement::{self, FieldDirection};
use warpbench_io::geometry::Point3;
use warpbench_io::geometry::Space;
use warpbench_io::itk_chain::{FieldOrChain, ItkChain, ItkStep};
use warpbench_io::itk_h5::H5Transform;
use warpbench_io::itk_tfm::{ItkAffine, ItkBSpline, ItkThinPlateSpline, ItkTransform};
use warpbench_solver::SolverError;
use warpbench_solver::brush::{Brush, PointwiseInverse};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::field::{PointInverse, SampledField};
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::brushed::Brushed;
use crate::start::Start;

/// A displacement field as a layer of the stack, in the direction its file states.
#[derive(Clone, Debug)]
pub struct FieldLayer {
    /// How messages name it: the file's path.
    pub origin: String,
    maps: FieldMaps,
    /// What the reader assumed where the file is silent (an OME-Zarr field without units, say), each prefixed with
    /// the file, for the user to see ([`crate::inputs::note_field_warnings`], the window's status).
    pub warnings: Vec<String>,
}

#[derive(Clone, Debug)]
enum FieldMaps {
    /// F = u-part itself (ITK's convention, and what a NIfTI field is taken to be): F(x) = x + D(x).
    Pullback(SampledField<Moving, Fixed>),
    /// The file holds F⁻¹ (NRRD `displacement field type:=modeling`): F⁻¹(y) = y + D(y); F is its point inverse.
    Forward(SampledField<Fixed, Moving>),
    /// An ITK transform file of B-splines (and affines) with no displacement field: F is its chain, evaluated as ITK
    /// evaluates it at every point (no grid to sample it on), F⁻¹ by Newton's method.
    Chain(Arc<ItkChain>),
}

impl FieldLayer {
    /// Reads a displacement field of any flavour ([`displacement::read_field_info`]), as a pull-back unless the file
    /// says it is the forward map; an ITK transform file of B-splines and affines without a field, which gives no
    /// grid to sample on, as its chain, applied exactly. Errors name the file.
    ///
    /// # Errors
    /// A file that cannot be read as a field; a transform file of linear transforms only (a starting transform) or
    /// holding a thin-plate spline (read as landmark pairs); a field the solver refuses (a vector that is not
    /// finite).
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let origin = path.display().to_string();
        let read = match displacement::read_field_or_chain(path)? {
            FieldOrChain::Field(read) => read,
            FieldOrChain::Chain(chain) => {
                if chain.affine().is_ok() {
                    return Err(anyhow!(
                        "{origin}: it holds only linear transforms, and no displacement field: it is a starting \
                         transform (--initial, or the window's starting transform from a file)"
                    ));
                }
                let spline =
                    chain.steps.iter().any(|s| matches!(s, ItkStep::Transform(ItkTransform::ThinPlateSpline(_))));
                if spline {
                    return Err(anyhow!(
                        "{origin}: a thin-plate spline transform file is read as its landmark pairs (--landmarks, or \
                         the window's Import landmarks)"
                    ));
                }
                return Ok(Self { origin, maps: FieldMaps::Chain(Arc::new(chain)), warnings: Vec::new() });
            }
        };
        let bad = |e: SolverError| anyhow!("{origin}: {e}");
        let maps = match read.direction {
            Some(FieldDirection::Forward) => {
                FieldMaps::Forward(SampledField::from_displacement_field(read.field).map_err(bad)?)
            }
            Some(FieldDirection::Pullback) | None => {
                FieldMaps::Pullback(SampledField::from_displacement_field(read.field).map_err(bad)?)
            }
        };
        let warnings = read.warnings.iter().map(|w| format!("{origin}: {w}")).collect();
        Ok(Self { origin, maps, warnings })
    }

    /// The layer of a pull-back field F (F(x) = x + D(x), fixed → moving).
    #[must_use]
    pub fn pullback(field: SampledField<Moving, Fixed>, origin: &str) -> Self {
        Self { origin: origin.to_owned(), maps: FieldMaps::Pullback(field), warnings: Vec::new() }
    }

    /// The layer of a forward field F⁻¹ (moving → fixed).
    #[must_use]
    pub fn forward(field: SampledField<Fixed, Moving>, origin: &str) -> Self {
        Self { origin: origin.to_owned(), maps: FieldMaps::Forward(field), warnings: Vec::new() }
    }

    /// F as the members of an ITK composite transform, in ITK's order (the last is applied first): the field on its
    /// own grid, or the chain's own transforms; `None` for a forward field, whose inverse no ITK class holds.
    #[must_use]
    pub fn itk_members(&self) -> Option<Vec<H5Transform<'_>>> {
        match &self.maps {
            FieldMaps::Pullback(f) => Some(vec![H5Transform::Field {
                dims: f.dims(),
                lps_from_index: f.lps_from_index(),
                displacements_lps: f.displacements(),
            }]),
            FieldMaps::Forward(_) => None,
            FieldMaps::Chain(chain) => Some(chain.steps.iter().map(H5Transform::from).collect()),
        }
    }

    /// F(x): fixed → moving.
    #[must_use]
    pub fn moving_from_fixed_raw(&self, x: [f64; 3]) -> [f64; 3] {
        match &self.maps {
            FieldMaps::Pullback(f) => f.apply_raw(x),
            FieldMaps::Forward(f) => PointInverse(f).apply_raw(x),
            FieldMaps::Chain(chain) => chain.apply(x),
        }
    }

    /// F⁻¹(p): moving → fixed.
    #[must_use]
    pub fn fixed_from_moving_raw(&self, p: [f64; 3]) -> [f64; 3] {
        match &self.maps {
            FieldMaps::Pullback(f) => PointInverse(f).apply_raw(p),
            FieldMaps::Forward(f) => f.apply_raw(p),
            FieldMaps::Chain(chain) => chain.apply_inverse(p),
        }
    }
}

/// The brush as a layer: its fitted inverse once a stroke has settled, or undone point by point while one is
/// dragged (cheaper to start, dearer per point).
#[derive(Clone, Debug)]
pub enum BrushLayer {
    Fitted(Arc<Brushed>),
    Pointwise(Arc<Brush>),
}

impl BrushLayer {
    fn brush(&self) -> &Brush {
        match self {
            Self::Fitted(b) => b.brush(),
            Self::Pointwise(b) => b,
        }
    }

    /// b⁻¹(x).
    fn inverse_raw(&self, x: [f64; 3]) -> [f64; 3] {
        match self {
            Self::Fitted(b) => b.inverse().apply_raw(x),
            Self::Pointwise(b) => PointwiseInverse(b).apply_raw(x),
        }
    }
}

/// The layers of a stack other than the landmark fit, in their order; any of them may be absent.
#[derive(Clone, Debug, Default)]
pub struct Layers {
    pub start: Option<Start>,
    pub field: Option<Arc<FieldLayer>>,
    pub brush: Option<BrushLayer>,
}

impl Layers {
    /// A starting transform and a fitted brush, as the subcommands read them from `--initial` and a session.
    #[must_use]
    pub fn new(start: Option<Start>, brushed: Option<Brushed>) -> Self {
        Self { start, field: None, brush: brushed.map(|b| BrushLayer::Fitted(Arc::new(b))) }
    }

    /// The fitted brush on top, if there is one.
    #[must_use]
    pub fn brushed(&self) -> Option<&Brushed> {
        match &self.brush {
            Some(BrushLayer::Fitted(b)) => Some(b),
            _ => None,
        }
    }

    /// The fewest pairs a fit on these layers needs: the method's without a base under it, none with one (the base
    /// alone is the warp).
    #[must_use]
    pub fn min_pairs(&self, method: &Method) -> usize {
        if self.has_base() { 0 } else { method.needs().min_pairs }
    }

    /// The warp's name in reports: `method`, `method on <field> on <start>` with a base it refines, or
    /// `<base> alone (N pairs; method needs K)` with too few pairs; `+ brush (N strokes)` with a brush on top.
    /// Without a field, what [`crate::start::describe`] and [`crate::brushed::describe`] say.
    #[must_use]
    pub fn describe(&self, method: &Method, pairs: usize) -> String {
        let needs = method.needs().min_pairs;
        let base: Vec<&str> =
            self.field.iter().map(|f| f.origin.as_str()).chain(self.start.iter().map(|s| s.origin.as_str())).collect();
        let core = match (base.is_empty(), pairs >= needs) {
            (true, _) => method.to_string(),
            (false, true) => format!("{method} on {}", base.join(" on ")),
            (false, false) => format!("{} alone ({pairs} pairs; {method} needs {needs})", base.join(" on ")),
        };
        match self.brush.as_ref().map(|b| b.brush().strokes().len()) {
            Some(1) => format!("{core} + brush (1 stroke)"),
            Some(n) => format!("{core} + brush ({n} strokes)"),
            None => core,
        }
    }

    /// B(x) = T₀(F(x)).
    #[must_use]
    pub fn base_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let x = self.field.as_ref().map_or(x, |f| f.moving_from_fixed_raw(x));
        self.start.as_ref().map_or(x, |s| s.moving_from_fixed().apply_raw(x))
    }

    /// B⁻¹(p) = F⁻¹(T₀⁻¹(p)).
    #[must_use]
    pub fn base_inverse_raw(&self, p: [f64; 3]) -> [f64; 3] {
        let p = self.start.as_ref().map_or(p, |s| s.fixed_from_moving().apply_raw(p));
        self.field.as_ref().map_or(p, |f| f.fixed_from_moving_raw(p))
    }

    /// Whether a starting transform or a field lies under the landmark fit (then the fit may have no pairs).
    #[must_use]
    pub fn has_base(&self) -> bool {
        self.start.is_some() || self.field.is_some()
    }
}

/// u = B ∘ r ∘ b⁻¹ (module docs), fixed → moving.
#[derive(Clone, Debug)]
pub struct StackPullback {
    layers: Layers,
    core: Landmarks<Moving, Fixed, Fixed>,
}

/// d = b ∘ F⁻¹ ∘ T₀⁻¹ ∘ s (module docs), moving → fixed.
#[derive(Clone, Debug)]
pub struct StackForward {
    layers: Layers,
    core: Landmarks<Fixed, Moving, Moving>,
}

/// One direction's landmark fit and the base around it (`Mid`: the space the fit maps into before the base acts).
#[derive(Clone, Debug)]
enum Landmarks<To: Space, From: Space, Mid: Space> {
    /// No field: the fit followed by T₀ (or its inverse), T₀ alone, or the fit alone: one warp of the method's
    /// family.
    Folded(FittedWarp<To, From>),
    /// On a field: the fit (`None` when the pairs are too few to refine the base), then the base.
    OnField(Option<FittedWarp<Mid, From>>),
}

/// Whether `pairs` pairs refine a base for `method` (else the base alone is the warp).
fn refines(method: &Method, pairs: usize) -> bool {
    pairs >= method.needs().min_pairs
}

impl StackPullback {
    /// u as one fitted warp of the method's family, on no other layer (a drag event's TPS).
    #[must_use]
    pub fn folded(u: FittedWarp<Moving, Fixed>) -> Self {
        Self { layers: Layers::default(), core: Landmarks::Folded(u) }
    }

    /// u = B ∘ r on `layers`' field (and starting transform) for a landmark layer r fitted elsewhere (a drag event's,
    /// [`crate::fit::DragFit`]), as [`Self::fit`] makes it; `layers` has no brush.
    #[must_use]
    pub fn on_field(layers: Layers, r: FittedWarp<Fixed, Fixed>) -> Self {
        debug_assert!(layers.field.is_some() && layers.brush.is_none(), "a drag's layers: a field, no brush");
        Self { layers, core: Landmarks::OnField(Some(r)) }
    }

    /// u at one point with b⁻¹ solved there to rounding (not read off its fitted spline, which the control texture
    /// and the exports sample): what the status bar shows and a click stores.
    #[must_use]
    pub fn apply_exact_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.core_raw(self.layers.brush.as_ref().map_or(x, |b| b.brush().invert_point(x)))
    }

    /// det ∇u at `x`: with a brush on top, det ∇(u ∘ b⁻¹)(x) = det ∇u(b⁻¹(x)) / det ∇b(b⁻¹(x)), from b's analytic
    /// Jacobian and b⁻¹ solved at `x` rather than differences through an inverse.
    #[must_use]
    pub fn det_jacobian_at(&self, x: [f64; 3]) -> f64 {
        let core = |y: [f64; 3]| match &self.core {
            Landmarks::Folded(u) => u.as_ref().jacobian_raw(y).determinant(),
            Landmarks::OnField(_) => Unbrushed(self).jacobian_raw(y).determinant(),
        };
        match &self.layers.brush {
            None => core(x),
            Some(b) => {
                let y = b.brush().invert_point(x);
                core(y) / b.brush().jacobian_raw(y).determinant()
            }
        }
    }

    /// u without the brush (B ∘ r).
    fn core_raw(&self, x: [f64; 3]) -> [f64; 3] {
        match &self.core {
            Landmarks::Folded(u) => u.as_ref().apply_raw(x),
            Landmarks::OnField(r) => self.layers.base_raw(r.as_ref().map_or(x, |r| r.as_ref().apply_raw(x))),
        }
    }

    /// Fits u on the pairs (`fixed[i]` ↔ `moving[i]`) over `fixed_box`, on top of `layers`' base.
    ///
    /// # Errors
    /// Too few pairs for `method` without a base under them, or a fit that fails (the solver's error, its pairs
    /// numbered 1-based among those given).
    pub fn fit(
        method: &Method,
        (fixed, moving): (&[Point3<Fixed>], &[Point3<Moving>]),
        fixed_box: Aabb<Fixed>,
        layers: Layers,
    ) -> Result<Self, SolverError> {
        let core = match (&layers.field, &layers.start) {
            (None, Some(start)) => Landmarks::Folded(crate::start::pullback(start, method, fixed, moving, fixed_box)?),
            (None, None) => Landmarks::Folded(method.fit(fixed, moving, fixed_box)?),
            (Some(_), _) if !refines(method, moving.len()) => Landmarks::OnField(None),
            (Some(_), _) => {
                let unbased: Vec<Point3<Fixed>> =
                    moving.iter().map(|p| Point3::from_array(layers.base_inverse_raw(p.coords()))).collect();
                Landmarks::OnField(Some(method.fit(fixed, &unbased, fixed_box)?))
            }
        };
        Ok(Self { layers, core })
    }

    /// The whole pull-back as one warp of the method's family, when it is one (no field, no brush): what the GPU
    /// evaluates itself and what an ITK transform file holds exactly.
    #[must_use]
    pub fn as_fitted(&self) -> Option<&FittedWarp<Moving, Fixed>> {
        match (&self.core, &self.layers.brush) {
            (Landmarks::Folded(u), None) => Some(u),
            _ => None,
        }
    }

    /// The layers under and over the landmark fit.
    #[must_use]
    pub fn layers(&self) -> &Layers {
        &self.layers
    }

    /// u sampled into the n³ control texture of [`crate::scene::control_grid`] over `fixed_box`: a hierarchical
    /// B-spline alone through its lattice's separable sampler, anything else texel by texel.
    ///
    /// # Errors
    /// A grid that cannot be made (n < 2, an empty box).
    pub fn control_texture(&self, fixed_box: Aabb<Fixed>, n: usize) -> anyhow::Result<(ControlGrid, ControlTexture)> {
        let grid = crate::scene::control_grid(fixed_box, n)?;
        Ok(match self.as_fitted() {
            Some(u) => (grid, ControlTexture::sample_fitted(u, grid)),
            None => (grid, ControlTexture::sample(self, grid)),
        })
    }

    /// u as the ITK transform file that holds it exactly ([`itk_transform_of`]).
    ///
    /// # Errors
    /// A field or a brush layer, which no ITK transform of a `.tfm` file holds exactly: the message says to write
    /// the warp as a displacement field instead.
    pub fn itk_transform(&self) -> anyhow::Result<ItkTransform> {
        if let Some(u) = self.as_fitted() {
            return Ok(itk_transform_of(u));
        }
        let layer = match &self.layers.field {
            Some(f) => format!("the displacement field {}", f.origin),
            None => "the brush".to_owned(),
        };
        Err(anyhow!(
            "an ITK transform file cannot hold this warp exactly: it has {layer} as a layer; write it as ITK's \
             HDF5 transform file over its displacement field (`warpbench transform --out NAME.h5`), or as a \
             displacement field (`warpbench field`)"
        ))
    }
}

impl StackPullback {
    /// u on a field as ITK's composite transform holds it: T₀, then F's own members, then the rest R = r ∘ b⁻¹ (the
    /// landmark fit and the brush), so that u = T₀ ∘ F ∘ R as ITK applies the list, last first. `None` without a
    /// field under the fit, or with a forward field (whose inverse no ITK class holds): then only a field sampled on
    /// a grid holds u.
    #[must_use]
    pub fn itk_composite(&self) -> Option<ItkComposite<'_>> {
        let Landmarks::OnField(r) = &self.core else { return None };
        let field = self.layers.field.as_ref()?.itk_members()?;
        let start = self.layers.start.as_ref().map(|s| {
            let t = s.moving_from_fixed();
            ItkTransform::Affine(ItkAffine::from_offset(t.linear(), t.translation()))
        });
        let rest = match (r, &self.layers.brush) {
            (None, None) => ItkRest::Identity,
            // ITK reads a thin-plate spline back only where its kernel transforms are registered (not SimpleITK's),
            // so only an affine or a B-spline fit is written as itself.
            (Some(r @ (FittedWarp::Linear(_) | FittedWarp::BSpline(_))), None) => ItkRest::Exact(itk_transform_of(r)),
            (fit, brush) => ItkRest::Sampled(Rest { fit: fit.as_ref(), brush: brush.as_ref() }),
        };
        Some(ItkComposite { start, field, rest })
    }
}

/// [`StackPullback::itk_composite`]: u = T₀ ∘ F ∘ R as the members of ITK's composite transform.
#[derive(Debug)]
pub struct ItkComposite<'a> {
    /// T₀ as an affine, when there is a starting transform.
    pub start: Option<ItkTransform>,
    /// F's own members ([`FieldLayer::itk_members`]).
    pub field: Vec<H5Transform<'a>>,
    pub rest: ItkRest<'a>,
}

/// R = r ∘ b⁻¹ of [`ItkComposite`], as ITK can hold it.
#[derive(Debug)]
pub enum ItkRest<'a> {
    /// Too few pairs to refine the base, and no brush: R is the identity, and no member holds it.
    Identity,
    /// An affine or a B-spline fit without a brush: the transform itself.
    Exact(ItkTransform),
    /// A thin-plate spline fit or a brush: R, to be sampled on a grid as a displacement field (zero outside it).
    Sampled(Rest<'a>),
}

/// R = r ∘ b⁻¹: fixed → fixed, the part of u above its base (either may be absent).
#[derive(Clone, Copy, Debug)]
pub struct Rest<'a> {
    fit: Option<&'a FittedWarp<Fixed, Fixed>>,
    brush: Option<&'a BrushLayer>,
}

impl Warp<Fixed, Fixed> for Rest<'_> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let x = self.brush.map_or(x, |b| b.inverse_raw(x));
        self.fit.map_or(x, |r| r.as_ref().apply_raw(x))
    }
}

impl Warp<Moving, Fixed> for StackPullback {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.core_raw(self.layers.brush.as_ref().map_or(x, |b| b.inverse_raw(x)))
    }
}

/// B ∘ r, the pull-back under the brush.
struct Unbrushed<'a>(&'a StackPullback);

impl Warp<Moving, Fixed> for Unbrushed<'_> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.0.core_raw(x)
    }
}

impl StackForward {
    /// d as one fitted warp of the method's family, on no other layer (a drag event's TPS).
    #[must_use]
    pub fn folded(d: FittedWarp<Fixed, Moving>) -> Self {
        Self { layers: Layers::default(), core: Landmarks::Folded(d) }
    }

    /// d = B⁻¹ ∘ s on `layers`' field for a landmark layer s fitted elsewhere ([`StackPullback::on_field`]).
    #[must_use]
    pub fn on_field(layers: Layers, s: FittedWarp<Moving, Moving>) -> Self {
        debug_assert!(layers.field.is_some() && layers.brush.is_none(), "a drag's layers: a field, no brush");
        Self { layers, core: Landmarks::OnField(Some(s)) }
    }

    /// Fits d on the pairs (`moving[i]` ↔ `fixed[i]`) over `moving_box`, on top of `layers`' base.
    ///
    /// # Errors
    /// As [`StackPullback::fit`].
    pub fn fit(
        method: &Method,
        (fixed, moving): (&[Point3<Fixed>], &[Point3<Moving>]),
        moving_box: Aabb<Moving>,
        layers: Layers,
    ) -> Result<Self, SolverError> {
        let core = match (&layers.field, &layers.start) {
            (None, Some(start)) => Landmarks::Folded(crate::start::forward(start, method, fixed, moving, moving_box)?),
            (None, None) => Landmarks::Folded(method.fit(moving, fixed, moving_box)?),
            (Some(_), _) if !refines(method, moving.len()) => Landmarks::OnField(None),
            (Some(_), _) => {
                let based: Vec<Point3<Moving>> =
                    fixed.iter().map(|q| Point3::from_array(layers.base_raw(q.coords()))).collect();
                Landmarks::OnField(Some(method.fit(moving, &based, moving_box)?))
            }
        };
        Ok(Self { layers, core })
    }

    /// The whole forward map as one warp of the method's family, when it is one (no field, no brush).
    #[must_use]
    pub fn as_fitted(&self) -> Option<&FittedWarp<Fixed, Moving>> {
        match (&self.core, &self.layers.brush) {
            (Landmarks::Folded(d), None) => Some(d),
            _ => None,
        }
    }

    /// d without the brush (the fit, then B⁻¹ on a field).
    fn core_raw(&self, p: [f64; 3]) -> [f64; 3] {
        match &self.core {
            Landmarks::Folded(d) => d.as_ref().apply_raw(p),
            Landmarks::OnField(s) => self.layers.base_inverse_raw(s.as_ref().map_or(p, |s| s.as_ref().apply_raw(p))),
        }
    }

    /// det ∇d at moving point `p`: the fit's analytic Jacobian (central differences through the field's inverse on a
    /// field), and with a brush on top det ∇(b ∘ d)(p) = det ∇b(d(p)) · det ∇d(p), from b's analytic Jacobian.
    #[must_use]
    pub fn det_jacobian_at(&self, p: [f64; 3]) -> f64 {
        let core = match &self.core {
            Landmarks::Folded(d) => d.as_ref().jacobian_raw(p).determinant(),
            Landmarks::OnField(_) => ForwardUnbrushed(self).jacobian_raw(p).determinant(),
        };
        match &self.layers.brush {
            None => core,
            Some(b) => b.brush().jacobian_raw(self.core_raw(p)).determinant() * core,
        }
    }
}

/// d without the brush, as a warp (its Jacobian by central differences).
struct ForwardUnbrushed<'a>(&'a StackForward);

impl Warp<Fixed, Moving> for ForwardUnbrushed<'_> {
    fn apply_raw(&self, p: [f64; 3]) -> [f64; 3] {
        self.0.core_raw(p)
    }
}

impl Warp<Fixed, Moving> for StackForward {
    fn apply_raw(&self, p: [f64; 3]) -> [f64; 3] {
        let y = self.core_raw(p);
        self.layers.brush.as_ref().map_or(y, |b| b.brush().apply_raw(y))
    }
}

/// Both directions of a stack, fitted on the same pairs and layers.
#[derive(Clone, Debug)]
pub struct FittedStack {
    pub pullback: StackPullback,
    pub forward: StackForward,
    /// Pairs the landmark layer was fitted on: 0 when the base alone is the warp.
    pub refined_on: usize,
}

impl FittedStack {
    /// Both directions ([`StackPullback::fit`], [`StackForward::fit`]).
    ///
    /// # Errors
    /// As [`StackPullback::fit`].
    pub fn fit(
        method: &Method,
        pairs: (&[Point3<Fixed>], &[Point3<Moving>]),
        (fixed_box, moving_box): (Aabb<Fixed>, Aabb<Moving>),
        layers: Layers,
    ) -> Result<Self, SolverError> {
        let refined_on = if refines(method, pairs.1.len()) || !layers.has_base() { pairs.1.len() } else { 0 };
        Ok(Self {
            pullback: StackPullback::fit(method, pairs, fixed_box, layers.clone())?,
            forward: StackForward::fit(method, pairs, moving_box, layers)?,
            refined_on,
        })
    }
}

/// The pull-back `moving_from_fixed` as the ITK transform that holds it exactly (a thin-plate spline by its centres and their images, a B-spline by its lattice, an affine
/// by its matrix and offset).
#[must_use]
pub fn itk_transform_of<To: Space, From: Space>(moving_from_fixed: &FittedWarp<To, From>) -> ItkTransform {
    match moving_from_fixed {
        FittedWarp::Linear(warp) => ItkTransform::Affine(ItkAffine::from_offset(warp.linear(), warp.translation())),
        FittedWarp::Tps(tps) => {
            let source_lps: Vec<[f64; 3]> = tps.centres().iter().map(Point3::coords).collect();
            let mut target_lps = vec![[0.0; 3]; source_lps.len()];
            tps.apply_batch_raw(&source_lps, &mut target_lps);
            ItkTransform::ThinPlateSpline(ItkThinPlateSpline { source_lps, target_lps })
        }
        FittedWarp::BSpline(spline) => {
            let lattice = spline.lattice();
            let spacing = lattice.spacing_mm();
            let min = lattice.min_mm();
            ItkTransform::BSpline(ItkBSpline {
                grid_size: lattice.dims(),
                grid_origin_lps: std::array::from_fn(|a| min[a] - spacing[a]),
                grid_spacing_mm: spacing,
                grid_direction: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                coefficients_mm: lattice.coefficients().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            })
        }
    }
}

#[cfg(test)]
// Exact equality is the law where the stack must be the same fit, bit for bit, as the code it replaces.
#[allow(clippy::float_cmp)]
mod tests {
    use nalgebra::{Matrix3, Rotation3};
    use warpbench_io::geometry::{Index, Lps, Transform};
    use warpbench_solver::brush::BrushStroke;
    use warpbench_solver::linear::AffineWarp;

    use super::*;

    fn start() -> Start {
        let r = Rotation3::from_euler_angles(0.05, -0.1, 0.08).into_inner() * Matrix3::from_diagonal_element(1.03);
        Start::new(AffineWarp::new(r, [4.0, -2.0, 6.0]), "start.tfm").expect("invertible")
    }

    /// D(x) = a few mm of smooth bumps on a 2 mm grid over ±80 mm.
    fn field() -> FieldLayer {
        let dims = [81, 81, 81];
        let lps_from_index =
            Transform::<Lps, Index>::from_linear_translation(Matrix3::from_diagonal_element(2.0), [-80.0; 3]);
        let mut d = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = [i as f64 * 2.0 - 80.0, j as f64 * 2.0 - 80.0, k as f64 * 2.0 - 80.0];
                    d.push([
                        (2.5 * (x[1] / 20.0).sin()) as f32,
                        (-2.0 * (x[2] / 25.0).cos()) as f32,
                        (1.5 * (x[0] / 18.0).sin()) as f32,
                    ]);
                }
            }
        }
        FieldLayer::pullback(SampledField::new(dims, lps_from_index, d).expect("field"), "field.nii.gz")
    }

    fn pairs() -> (Vec<Point3<Fixed>>, Vec<Point3<Moving>>) {
        let fixed: Vec<Point3<Fixed>> = [
            [0.0, 0.0, 0.0],
            [40.0, 5.0, -3.0],
            [-20.0, 30.0, 10.0],
            [5.0, -25.0, 30.0],
            [10.0, 10.0, -35.0],
            [-30.0, -20.0, -10.0],
            [25.0, -30.0, 15.0],
        ]
        .map(Point3::from_array)
        .to_vec();
        let moving = fixed
            .iter()
            .enumerate()
            .map(|(i, q)| {
                let [x, y, z] = q.coords();
                Point3::new(x + 3.0 + 0.4 * i as f64, y - 2.0 + 0.3 * (i % 3) as f64, z + 5.0 - 0.2 * i as f64)
            })
            .collect();
        (fixed, moving)
    }

    fn boxes() -> (Aabb<Fixed>, Aabb<Moving>) {
        (
            Aabb::new(Point3::new(-60.0, -60.0, -60.0), Point3::new(60.0, 60.0, 60.0)),
            Aabb::new(Point3::new(-70.0, -70.0, -70.0), Point3::new(70.0, 70.0, 70.0)),
        )
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
    }

    const PROBES: [[f64; 3]; 6] = [
        [1.0, 2.0, 3.0],
        [-33.0, 12.5, 40.0],
        [50.0, -45.0, -20.0],
        [-10.0, -10.0, 10.0],
        [20.0, 35.0, -50.0],
        [0.5, -55.0, 22.0],
    ];

    /// With every layer, u and d are the compositions written out here from the layers' own maps, and both hit
    /// the pairs: u(qᵢ) = pᵢ and d(pᵢ) = qᵢ away from the brush.
    #[test]
    fn the_stack_is_its_layers_composed_in_order() {
        let method = Method::Tps { stiffness: 0.0 };
        let (fixed, moving) = pairs();
        let s = start();
        let f = Arc::new(field());
        let stroke = BrushStroke { centre_mm: [45.0, 45.0, 45.0], displacement_mm: [0.0, 3.0, 0.0], radius_mm: 12.0 };
        let brushed = Arc::new(Brushed::new(&[stroke], "the brush").expect("brush").expect("a stroke"));
        let layers =
            Layers { start: Some(s.clone()), field: Some(f.clone()), brush: Some(BrushLayer::Fitted(brushed.clone())) };
        let stack = FittedStack::fit(&method, (&fixed, &moving), boxes(), layers).expect("fit");
        assert_eq!(stack.refined_on, fixed.len());
        assert!(stack.pullback.as_fitted().is_none() && stack.pullback.itk_transform().is_err());

        // Written out: B = T₀ ∘ F, r fitted on qᵢ → B⁻¹(pᵢ), s on pᵢ → B(qᵢ).
        let base = |x: [f64; 3]| s.moving_from_fixed().apply_raw(f.moving_from_fixed_raw(x));
        let base_inverse = |p: [f64; 3]| f.fixed_from_moving_raw(s.fixed_from_moving().apply_raw(p));
        let unbased: Vec<Point3<Fixed>> = moving.iter().map(|p| Point3::from_array(base_inverse(p.coords()))).collect();
        let based: Vec<Point3<Moving>> = fixed.iter().map(|q| Point3::from_array(base(q.coords()))).collect();
        let r: FittedWarp<Fixed, Fixed> = method.fit(&fixed, &unbased, boxes().0).expect("r");
        let sf: FittedWarp<Moving, Moving> = method.fit(&moving, &based, boxes().1).expect("s");
        for x in PROBES {
            let u = base(r.as_ref().apply_raw(brushed.inverse().apply_raw(x)));
            assert!(close(stack.pullback.apply_raw(x), u, 1e-9), "u at {x:?}");
            let d = brushed.brush().apply_raw(base_inverse(sf.as_ref().apply_raw(x)));
            assert!(close(stack.forward.apply_raw(x), d, 1e-9), "d at {x:?}");
        }
        // The brush acts far from the pairs, so the pairs are hit through the whole stack.
        for (q, p) in fixed.iter().zip(&moving) {
            assert!(close(stack.pullback.apply_raw(q.coords()), p.coords(), 1e-5), "u({q:?})");
            assert!(close(stack.forward.apply_raw(p.coords()), q.coords(), 1e-5), "d({p:?})");
        }
    }

    /// Without a field the stack is what [`crate::start`] has always fitted: one warp of the method's family, which
    /// the control texture samples through and the ITK file holds; with too few pairs the base alone is the warp.
    #[test]
    fn without_a_field_the_start_folds_into_the_fit_and_too_few_pairs_leave_the_base() {
        let method = Method::Tps { stiffness: 0.0 };
        let (fixed, moving) = pairs();
        let s = start();
        let layers = Layers { start: Some(s.clone()), ..Layers::default() };
        let stack = FittedStack::fit(&method, (&fixed, &moving), boxes(), layers).expect("fit");
        let u = stack.pullback.as_fitted().expect("one warp");
        let direct = crate::start::pullback(&s, &method, &fixed, &moving, boxes().0).expect("start");
        for x in PROBES {
            assert_eq!(u.as_ref().apply_raw(x), direct.as_ref().apply_raw(x));
        }
        assert!(matches!(stack.pullback.itk_transform().expect("exact"), ItkTransform::ThinPlateSpline(_)));
        let (grid, texture) = stack.pullback.control_texture(boxes().0, 8).expect("texture");
        let (_, by_hand) = crate::fit::control_texture(u, boxes().0, 8).expect("texture");
        assert_eq!(texture.texels, by_hand.texels);
        assert_eq!(grid.dims, [8, 8, 8]);

        // Too few pairs: the base alone (T₀ ∘ F), and no pairs without a base is an error.
        let f = Arc::new(field());
        let layers = Layers { start: Some(s.clone()), field: Some(f.clone()), brush: None };
        let alone = FittedStack::fit(&method, (&fixed[..2], &moving[..2]), boxes(), layers).expect("base alone");
        assert_eq!(alone.refined_on, 0);
        for x in PROBES {
            let want = s.moving_from_fixed().apply_raw(f.moving_from_fixed_raw(x));
            assert!(close(alone.pullback.apply_raw(x), want, 1e-12), "{x:?}");
            let back = alone.forward.apply_raw(want);
            assert!(close(back, x, 1e-6), "d(u(x)) = x at {x:?}: {back:?}");
        }
        let err = FittedStack::fit(&method, (&fixed[..2], &moving[..2]), boxes(), Layers::default());
        assert!(err.is_err());

        // Reports name the layers as the start's and the brush's own descriptions do.
        let with_start = Layers { start: Some(s.clone()), ..Layers::default() };
        assert_eq!(with_start.describe(&method, 7), crate::start::describe(&method, 4, 7, Some(&s)));
        assert_eq!(with_start.describe(&method, 2), crate::start::describe(&method, 4, 2, Some(&s)));
        let on_field = Layers { start: Some(s), field: Some(f), brush: None };
        assert_eq!(on_field.describe(&method, 7), "tps on field.nii.gz on start.tfm");
        assert_eq!((on_field.min_pairs(&method), Layers::default().min_pairs(&method)), (0, 4));
    }

    /// Every layer: the start, the field and a brush stroke around [45, 45, 45] mm.
    fn every_layer() -> Layers {
        let stroke = BrushStroke { centre_mm: [45.0, 45.0, 45.0], displacement_mm: [0.0, 3.0, 0.0], radius_mm: 12.0 };
        let brushed = Arc::new(Brushed::new(&[stroke], "the brush").expect("brush").expect("a stroke"));
        Layers { start: Some(start()), field: Some(Arc::new(field())), brush: Some(BrushLayer::Fitted(brushed)) }
    }

    /// det ∇d is the determinant of d's central differences (h = 1e-3 mm), with no layer (the fit's analytic
    /// Jacobian), on a start, and on every layer with a brush stroke over one probe (the brush's chain rule). The
    /// probes sit off the field's 2 mm grid, so a difference step never crosses a cell face of its trilinear
    /// samples: the quotient is then off by h²/6 · |∂³d| and the rounding of d over h (1e-13 · 100 mm / 1e-3 mm),
    /// and on a field by the field's own central differences; 1e-6 without a field, 1e-4 with one.
    #[test]
    fn the_forward_det_is_the_derivative_of_the_forward_map() {
        let method = Method::Tps { stiffness: 0.0 };
        let (fixed, moving) = pairs();
        let fit = |layers| FittedStack::fit(&method, (&fixed, &moving), boxes(), layers).expect("fit").forward;
        let cases = [
            (Layers::default(), 1e-6),
            (Layers { start: Some(start()), ..Layers::default() }, 1e-6),
            (every_layer(), 1e-4),
        ];
        let probes: Vec<[f64; 3]> = PROBES.iter().chain(&[[40.0, 43.0, 47.0]]).map(|p| p.map(|v| v + 0.37)).collect();
        for (i, (layers, tol)) in cases.into_iter().enumerate() {
            let d = fit(layers);
            for &p in &probes {
                let h = 1e-3;
                let j = Matrix3::from_fn(|r, c| {
                    let (mut a, mut b) = (p, p);
                    a[c] += h;
                    b[c] -= h;
                    (d.apply_raw(a)[r] - d.apply_raw(b)[r]) / (2.0 * h)
                });
                let (got, want) = (d.det_jacobian_at(p), j.determinant());
                assert!((got - want).abs() <= tol, "case {i} at {p:?}: {got} vs {want}");
            }
        }
        // The last probe is under the stroke: there the brush changes det ∇d, so its factor was checked.
        let p = probes[probes.len() - 1];
        let unbrushed = fit(Layers { brush: None, ..every_layer() });
        let (with, without) = (fit(every_layer()).det_jacobian_at(p), unbrushed.det_jacobian_at(p));
        assert!((with - without).abs() > 0.01, "the brush acts at {p:?}: {with} vs {without}");
    }

    /// A field read as the forward map (F⁻¹ in the file) is the same layer as its pull-back, inverted.
    #[test]
    fn a_forward_field_is_the_same_layer_inverted() {
        let f = field();
        let FieldMaps::Pullback(pullback) = &f.maps else { unreachable!("made as a pull-back") };
        // Sample F⁻¹ on the same grid and take it as a forward field: F from it is F again, to the grid's accuracy.
        let dims = pullback.dims();
        let t = *pullback.lps_from_index();
        let mut d = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let y = t.apply_point(Point3::<Index>::new(i as f64, j as f64, k as f64)).coords();
                    let x = f.fixed_from_moving_raw(y);
                    d.push([(x[0] - y[0]) as f32, (x[1] - y[1]) as f32, (x[2] - y[2]) as f32]);
                }
            }
        }
        let forward = FieldLayer::forward(SampledField::new(dims, t, d).expect("field"), "forward.nrrd");
        for x in PROBES {
            let (a, b) = (forward.moving_from_fixed_raw(x), f.moving_from_fixed_raw(x));
            // Trilinear resampling of a 2.5 mm / 20 mm sine on a 2 mm grid: second differences below 0.05 mm.
            assert!(close(a, b, 0.05), "{x:?}: {a:?} vs {b:?}");
        }
    }
}
