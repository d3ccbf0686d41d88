//! Encoding and decoding the per-step bulk messages of one group of 10^4 fibres of 7
//! segments (7 × 10^4 points): FlowSamples (12 numbers per point, 6.7 MB), a complete
//! FiberGroupState (12 per point, 6.7 MB) and FiberGroupMetrics (6 numbers per fibre,
//! 0.48 MB), through the generic serde path and through the bulk path `encode` / `decode`
//! use.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_messages::codec::{serde_decode, serde_encode};
use fiberflow_messages::{
    decode, encode, FiberGroupMetrics, FiberGroupState, FlowSamples, Message, SCHEMA_VERSION,
};

const FIBERS: usize = 10_000;
const SEGMENTS: usize = 7;

fn numbers(n: usize, seed: f64) -> Vec<f64> {
    (0..n).map(|i| (i as f64 * 0.618 + seed).sin()).collect()
}

fn samples() -> FlowSamples {
    let points = FIBERS * SEGMENTS;
    FlowSamples {
        schema_version: SCHEMA_VERSION,
        group: "case1".into(),
        step: 12,
        t_plus: 2.4,
        first_fiber: 0,
        group_fibers: FIBERS as u32,
        velocity: numbers(3 * points, 0.1),
        velocity_gradient: numbers(9 * points, 0.2),
    }
}

fn state() -> FiberGroupState {
    let points = FIBERS * SEGMENTS;
    FiberGroupState {
        schema_version: SCHEMA_VERSION,
        group: "case1".into(),
        step: 12,
        t_plus: 2.4,
        first_fiber: 0,
        group_fibers: FIBERS as u32,
        segments_per_fiber: vec![SEGMENTS as u32; FIBERS],
        segment_length: vec![3.0; FIBERS],
        diameter: vec![0.232; FIBERS],
        density_ratio: vec![1150.0; FIBERS],
        layer: vec![1; FIBERS],
        centre: numbers(3 * points, 0.3),
        axis: numbers(3 * points, 0.4),
        velocity: numbers(3 * points, 0.5),
        angular_velocity: numbers(3 * points, 0.6),
        hydro_force: vec![],
        contact_segment: vec![],
        contact_force: vec![],
        contacts: vec![],
    }
}

fn metrics() -> FiberGroupMetrics {
    FiberGroupMetrics {
        schema_version: SCHEMA_VERSION,
        group: "case1".into(),
        step: 12,
        t_plus: 2.4,
        first_fiber: 0,
        group_fibers: FIBERS as u32,
        centre_of_mass: numbers(3 * FIBERS, 0.7),
        z1: numbers(FIBERS, 0.8),
        sigma2: numbers(FIBERS, 0.9),
        end_to_end: numbers(FIBERS, 1.0),
        mean_abs_z1: 0.5,
        mean_sigma2: 0.1,
    }
}

/// Serde and bulk encoding and decoding of `m` in a group named `name`.
fn codec<M: Message>(c: &mut Criterion, name: &str, m: &M) {
    let bytes = encode(m);
    let mut g = c.benchmark_group(name);
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.bench_function("encode_serde", |b| b.iter(|| serde_encode(m)));
    g.bench_function("encode_bulk", |b| b.iter(|| encode(m)));
    g.bench_function("decode_serde", |b| b.iter(|| serde_decode::<M>(&bytes)));
    g.bench_function("decode_bulk", |b| b.iter(|| decode::<M>(&bytes)));
    g.finish();
}

fn bench(c: &mut Criterion) {
    codec(c, "flow_samples_1e4_fibers", &samples());
    codec(c, "fiber_state_1e4_fibers", &state());
    codec(c, "fiber_metrics_1e4_fibers", &metrics());
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
