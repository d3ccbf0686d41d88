//! The launcher: launch files (schema, checks, `--set`), the key reference, node wiring
//! and supervision (process groups, restart on failure), coupled checkpoints and their
//! manifests, the run lock, and the analysis a run ends with. The `fiberflow` binary is
//! argument parsing over this crate.

#[cfg(test)]
mod access_tests;
pub mod analyze;
pub mod coupled;
#[cfg(test)]
mod docs_tests;
pub mod hosts;
pub mod keys;
pub mod launch;
pub mod launchfile;
pub mod loading;
pub mod nodes;
pub mod overrides;
pub mod panics;
pub mod progress;
pub mod run_lock;
pub mod scheduling;
pub mod spinup_cmd;
pub mod supervise;
