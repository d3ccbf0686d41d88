//! Direct numerical simulation of incompressible plane channel flow (paper §3, eq. 13–14).
//!
//! Second-order finite differences on a staggered grid, low-storage RK3 with a projection
//! per substep, a direct FFT + tridiagonal pressure solver and Crank–Nicolson wall-normal
//! diffusion. No transport dependency: plain state plus [`Solver::step`].

pub mod checkpoint;
pub mod config;
pub mod correct;
pub mod error;
pub mod field;
pub mod grid;
pub mod implicit;
pub mod init;
pub mod perturb;
pub mod poisson;
pub mod regrid;
pub mod rhs;
pub mod sample;
pub mod slice;
pub mod solver;
pub mod spread;
pub mod stats;
pub mod timestep;

pub use config::{DnsConfig, Forcing, InitialField};
pub use error::DnsError;
pub use grid::Grid;
pub use solver::{Solver, StepReport};
