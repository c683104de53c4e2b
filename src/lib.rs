//! moreau: Moreau's catching-up scheme for first-order nonsmooth dynamics.
//!
//! This facade re-exports the workspace's library crates; the cross-crate tests (the papers'
//! examples) live in `tests/`.

pub use moreau_core as core;
pub use moreau_integrate as integrate;
pub use moreau_solve as solve;
