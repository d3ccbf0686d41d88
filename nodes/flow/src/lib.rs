//! The flow node: serves velocity and velocity-gradient samples to fibre groups, from the
//! channel DNS or from an analytic flow, and runs DNS spin-up to developed turbulence.

pub mod analytic;
pub mod checkpoint;
pub mod config;
mod coupling;
pub mod error;
pub mod fast_exp;
pub mod feedback;
pub mod field_steps;
mod lockstep;
mod outgoing;
pub mod pair_shares;
pub mod run;
pub mod sampling;
pub mod self_induced;
pub mod serve;
pub mod spinup;
pub mod step_times;

pub use config::{FlowNodeConfig, FlowSource};
pub use error::FlowError;
