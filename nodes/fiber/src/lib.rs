//! The fibre node: owns one fibre group (a paper case or any user set-up), integrates the
//! Lindström–Uesaka model in lockstep with the flow node and publishes states and metrics.

pub mod config;
mod exchange;
mod flow_watch;
mod lockstep;
mod piece;
mod publish;
pub mod serve;
mod tally;

pub use config::FiberNodeConfig;
