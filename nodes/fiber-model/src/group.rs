//! A group of fibres stepped together (one fibre node owns one or more groups); fibres
//! are independent (no fibre–fibre interaction, one-way coupling), so they step in parallel.

use crate::error::FibreError;
use crate::fibre::Fibre;
use crate::step::{step, FluidSample, ModelParams};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Fibres sharing model parameters, plus a per-fibre tag (initial layer).
#[derive(Debug, Clone)]
pub struct FibreGroup {
    pub params: ModelParams,
    pub fibres: Vec<Fibre>,
    /// Offsets of each fibre's first segment in the flat segment list.
    offsets: Vec<usize>,
}

impl FibreGroup {
    pub fn new(params: ModelParams, fibres: Vec<Fibre>) -> Self {
        let mut offsets = Vec::with_capacity(fibres.len() + 1);
        let mut o = 0;
        for f in &fibres {
            offsets.push(o);
            o += f.len();
        }
        offsets.push(o);
        Self {
            params,
            fibres,
            offsets,
        }
    }

    /// Total number of segments.
    pub fn segment_count(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
    }

    /// Segment centres in flat order (where the flow must be sampled).
    pub fn segment_centres(&self) -> Vec<Vector3<f64>> {
        self.fibres
            .iter()
            .flat_map(|f| f.segments.iter().map(|s| s.r))
            .collect()
    }

    /// Sets every segment's velocity to the fluid's (linear and angular).
    pub fn set_velocity_to_fluid(&mut self, fluid: &[FluidSample]) -> Result<(), FibreError> {
        self.check(fluid)?;
        for (f, &o) in self.fibres.iter_mut().zip(&self.offsets) {
            for (i, s) in f.segments.iter_mut().enumerate() {
                s.v = fluid[o + i].vel;
                s.w = fluid[o + i].rotation();
            }
        }
        Ok(())
    }

    fn check(&self, fluid: &[FluidSample]) -> Result<(), FibreError> {
        if fluid.len() != self.segment_count() {
            return Err(FibreError::SampleCount {
                expected: self.segment_count(),
                got: fluid.len(),
            });
        }
        Ok(())
    }

    /// Advances every fibre by `dt` (in parallel; deterministic: fibres are independent).
    pub fn step(&mut self, fluid: &[FluidSample], dt: f64) -> Result<(), FibreError> {
        self.check(fluid)?;
        let params = self.params;
        let offsets = &self.offsets;
        self.fibres
            .par_iter_mut()
            .enumerate()
            .try_for_each(|(k, f)| {
                let s = &fluid[offsets[k]..offsets[k + 1]];
                step(&params, f, s, dt).map_err(|e| match e {
                    FibreError::Singular { .. } => FibreError::Singular { fibre: k },
                    other => other,
                })
            })
    }

    /// Advances on the current thread only (for single-thread benchmarks).
    pub fn step_serial(&mut self, fluid: &[FluidSample], dt: f64) -> Result<(), FibreError> {
        self.check(fluid)?;
        for (k, f) in self.fibres.iter_mut().enumerate() {
            let s = &fluid[self.offsets[k]..self.offsets[k + 1]];
            step(&self.params, f, s, dt)?;
        }
        Ok(())
    }
}
