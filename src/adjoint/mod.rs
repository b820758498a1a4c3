//! Adjoint systems: one file per forward stage, mirroring `src/systems` name for name
//! (`systems/p2g.rs::p2g` ↔ `adjoint/p2g.rs::p2g_adjoint`), run in a `SubstepAdjoint` schedule
//! whose sets are chained in exactly the reverse order.
//!
//! Not implemented yet: the forward simulator is the foundation they build on, and the
//! adjoint work is tracked as its own issue. Until then no forward schedule allocates tape or
//! adjoint buffers, and no command claims to compute a gradient.
