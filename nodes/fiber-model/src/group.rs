//! A group of fibres stepped together (one fibre node owns one or more groups); fibres
//! are independent (no fibre–fibre interaction, one-way coupling), so they step in parallel.

use crate::batch;
use crate::error::FibreError;
use crate::fibre::Fibre;
use crate::lanes::LANES;
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

    /// Advances every fibre by `dt`, in parallel, four fibres at a time where they can
    /// share SIMD lanes ([`batch`]); deterministic: fibres are independent and every
    /// fibre gets the same bits batched or not.
    pub fn step(&mut self, fluid: &[FluidSample], dt: f64) -> Result<(), FibreError> {
        self.check(fluid)?;
        let params = self.params;
        let offsets = &self.offsets;
        self.fibres
            .par_chunks_mut(LANES)
            .enumerate()
            .try_for_each_init(batch::Scratch::default, |scratch, (c, chunk)| {
                step_chunk(&params, chunk, c * LANES, offsets, fluid, dt, scratch)
            })
    }

    /// [`Self::step`] on the current thread only (for single-thread benchmarks).
    pub fn step_serial(&mut self, fluid: &[FluidSample], dt: f64) -> Result<(), FibreError> {
        self.check(fluid)?;
        let mut scratch = batch::Scratch::default();
        for (c, chunk) in self.fibres.chunks_mut(LANES).enumerate() {
            step_chunk(
                &self.params,
                chunk,
                c * LANES,
                &self.offsets,
                fluid,
                dt,
                &mut scratch,
            )?;
        }
        Ok(())
    }

    /// One fibre at a time with [`step`] on the current thread, never batched (the
    /// reference the batched step is compared with, in tests and benchmarks).
    pub fn step_serial_unbatched(
        &mut self,
        fluid: &[FluidSample],
        dt: f64,
    ) -> Result<(), FibreError> {
        self.check(fluid)?;
        for (k, f) in self.fibres.iter_mut().enumerate() {
            step_one(&self.params, f, k, &self.offsets, fluid, dt)?;
        }
        Ok(())
    }
}

/// Steps the fibres `first..first + chunk.len()`: together if [`batch::eligible`], else
/// one by one.
fn step_chunk(
    params: &ModelParams,
    chunk: &mut [Fibre],
    first: usize,
    offsets: &[usize],
    fluid: &[FluidSample],
    dt: f64,
    scratch: &mut batch::Scratch,
) -> Result<(), FibreError> {
    if batch::eligible(params, chunk) {
        let samples: [&[FluidSample]; LANES] = std::array::from_fn(|j| {
            let k = (first + j).min(first + chunk.len() - 1);
            &fluid[offsets[k]..offsets[k + 1]]
        });
        return batch::step(params, chunk, &samples[..chunk.len()], dt, scratch).map_err(|lane| {
            FibreError::Singular {
                fibre: first + lane,
            }
        });
    }
    for (j, f) in chunk.iter_mut().enumerate() {
        step_one(params, f, first + j, offsets, fluid, dt)?;
    }
    Ok(())
}

fn step_one(
    params: &ModelParams,
    f: &mut Fibre,
    k: usize,
    offsets: &[usize],
    fluid: &[FluidSample],
    dt: f64,
) -> Result<(), FibreError> {
    step(params, f, &fluid[offsets[k]..offsets[k + 1]], dt).map_err(|e| match e {
        FibreError::Singular { .. } => FibreError::Singular { fibre: k },
        other => other,
    })
}
