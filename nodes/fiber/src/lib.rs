//! The fibre node: owns one fibre group (a paper case or any user set-up), integrates the
//! Lindström–Uesaka model in lockstep with the flow node and publishes states and metrics.

pub mod config;
mod exchange;
mod flow_watch;
pub mod serve;

pub use config::FiberNodeConfig;
