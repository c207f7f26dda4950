//! The solver's integration tests, one module per file beside this one, built as one test binary: each binary would
//! link the crate again and compile its generics again at the crate's opt-level, 14 times over. In one binary the
//! long registrations also run beside the short tests instead of after them.
//!
//! Run one file's tests with its module name as the filter, e.g. `cargo test -p warpbench-solver --test solver tps::`.

mod common;
mod suggest_case;

mod accuracy;
mod align;
mod bspline;
mod field_itk;
mod invert;
mod linear;
mod pairs;
mod register;
mod register_accuracy;
mod stiffness;
mod suggest;
mod synthetic;
mod tps;
mod tps_drag;
