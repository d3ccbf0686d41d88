//! The Lindström–Uesaka flexible-fibre model (paper §2, Appendices A and B): chains of
//! rigid cylindrical segments with implicit joint forces, viscous (Cox/Kim & Karrila) and
//! inertial cross-flow hydrodynamics, plus joint bending stiffness, gravity and wall
//! contact. No transport or message dependency: plain state plus [`step::step`].

pub mod batch;
pub mod cases;
pub mod checkpoint;
pub mod contact;
pub mod dense;
pub mod error;
pub mod fiber;
pub mod group;
pub mod hydro;
pub mod lanes;
pub mod metrics;
pub mod step;
pub mod suspension;

pub use error::FiberError;
pub use fiber::{Fiber, Segment};
pub use hydro::DragModel;
pub use step::{FluidSample, ModelParams};
