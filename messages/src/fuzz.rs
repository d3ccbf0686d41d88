//! Structure-aware random messages for robustness tests: valid CDR of every message type
//! with random lengths and values (NaN, infinities, huge steps, mismatched arrays), so
//! the checks after decoding are exercised, not only the decoder. `nonsense` makes
//! messages that always break at least one rule a receiver can check.

use crate::kind::Kind;
use crate::types::*;
use crate::{encode, SCHEMA_VERSION};

/// xorshift64* — small, deterministic, good enough to spread cases.
#[derive(Debug, Clone)]
pub struct Rng {
    x: u64,
    /// While set, floats are ordinary and lengths exact (a message that may pass).
    tidy: bool,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self {
            x: seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1,
            tidy: false,
        }
    }
    pub fn next_u64(&mut self) -> u64 {
        self.x ^= self.x >> 12;
        self.x ^= self.x << 25;
        self.x ^= self.x >> 27;
        self.x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }
    fn chance(&mut self, one_in: u64) -> bool {
        self.below(one_in) == 0
    }
    /// A float: mostly ordinary, sometimes NaN, ±inf, huge or tiny.
    pub fn float(&mut self) -> f64 {
        if self.tidy {
            return (self.below(2_000_001) as f64 - 1e6) * 1e-3;
        }
        match self.below(40) {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => 1e300,
            4 => -1e-300,
            _ => (self.below(2_000_001) as f64 - 1e6) * 1e-3,
        }
    }
    fn floats(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.float()).collect()
    }
    /// A length near `n`: usually `n`, sometimes off by a little or a lot.
    fn len_near(&mut self, n: usize) -> usize {
        if self.tidy {
            return n;
        }
        match self.below(8) {
            0 => n + 1 + self.below(5) as usize,
            1 => n.saturating_sub(1 + self.below(5) as usize),
            2 => self.below(64) as usize,
            _ => n,
        }
    }
    /// (first_fiber, group_fibers) of a message about `n` fibres: usually the whole
    /// group, sometimes a slice that does not fit.
    fn piece(&mut self, n: usize) -> (u32, u32) {
        let whole = (0, n.max(1) as u32);
        if self.tidy {
            return whole;
        }
        match self.below(10) {
            0 => (self.below(3) as u32, self.below(3) as u32),
            1 => (n as u32 + 1, n as u32),
            _ => whole,
        }
    }
    fn step(&mut self) -> u64 {
        match self.below(10) {
            0 => u64::MAX - self.below(10),
            1 => 1 << 40,
            _ => self.below(400),
        }
    }
    fn name(&mut self, known: &[String]) -> String {
        if !known.is_empty() && !self.chance(4) {
            return known[self.below(known.len() as u64) as usize].clone();
        }
        match self.below(4) {
            0 => String::new(),
            1 => "flow".into(),
            _ => format!("intruder{}", self.below(1000)),
        }
    }
}

/// The kinds of message a payload can be made for.
pub const KINDS: [Kind; 10] = [
    Kind::RunAnnouncement,
    Kind::FlowSlice,
    Kind::FlowStatus,
    Kind::FlowProfiles,
    Kind::FlowSamples,
    Kind::FiberGroupState,
    Kind::FiberGroupMetrics,
    Kind::Heartbeat,
    Kind::FiberFreeStep,
    Kind::FiberContactSolved,
];

fn state(r: &mut Rng, groups: &[String]) -> FiberGroupState {
    let nf = r.below(6) as usize;
    let spf: Vec<u32> = (0..nf)
        .map(|_| {
            if r.chance(20) {
                0
            } else {
                1 + r.below(8) as u32
            }
        })
        .collect();
    let nseg: usize = spf.iter().map(|&n| n as usize).sum();
    let (a, b, c, d) = (
        r.len_near(3 * nseg),
        r.len_near(3 * nseg),
        r.len_near(3 * nseg),
        r.len_near(3 * nseg),
    );
    // two-way forces: absent (one-way) half the time
    let e = if r.chance(2) { 0 } else { r.len_near(3 * nseg) };
    // contact's forces and counts: absent (no contact) half the time
    let touched = if r.chance(2) {
        0
    } else {
        r.below(nseg as u64 + 1) as usize
    };
    let mut contact_segment: Vec<u32> = (0..r.len_near(touched))
        .map(|_| r.below(nseg as u64 + 1) as u32)
        .collect();
    if r.tidy {
        contact_segment.sort_unstable();
        contact_segment.dedup();
        contact_segment.retain(|&i| (i as usize) < nseg);
    }
    let (g, h) = (
        r.len_near(3 * contact_segment.len()),
        r.len_near(contact_segment.len()),
    );
    let (first_fiber, group_fibers) = r.piece(nf);
    FiberGroupState {
        schema_version: SCHEMA_VERSION,
        group: r.name(groups),
        step: r.step(),
        t_plus: r.float(),
        first_fiber,
        group_fibers,
        segments_per_fiber: spf,
        segment_length: {
            let n = r.len_near(nf);
            r.floats(n)
        },
        diameter: {
            let n = r.len_near(nf);
            r.floats(n)
        },
        density_ratio: {
            let n = r.len_near(nf);
            r.floats(n)
        },
        layer: (0..r.len_near(nf)).map(|_| r.below(256) as u8).collect(),
        centre: r.floats(a),
        axis: r.floats(b),
        velocity: r.floats(c),
        angular_velocity: r.floats(d),
        hydro_force: r.floats(e),
        contact_segment,
        contact_force: r.floats(g),
        contacts: (0..h).map(|_| 1 + r.below(9) as u32).collect(),
    }
}

/// A random, structurally valid payload of `kind` (it may or may not make sense:
/// one in three is tidy — ordinary values, consistent lengths — and usually passes).
pub fn random_payload(kind: Kind, r: &mut Rng, groups: &[String]) -> Vec<u8> {
    r.tidy = r.chance(3);
    let b = payload(kind, r, groups);
    r.tidy = false;
    b
}

/// Long (≈125 lines): one arm per message type, each a few lines.
fn payload(kind: Kind, r: &mut Rng, groups: &[String]) -> Vec<u8> {
    match kind {
        Kind::RunAnnouncement => encode(&RunAnnouncement {
            schema_version: SCHEMA_VERSION,
            run_id: r.name(&[]),
            config_digest: format!("{:x}", r.next_u64()),
            groups: (0..r.below(4)).map(|_| r.name(groups)).collect(),
            steps: r.step(),
            dt_plus: r.float(),
            box_plus: {
                let n = r.len_near(3);
                r.floats(n)
            },
        }),
        Kind::FlowStatus => encode(&FlowStatus {
            schema_version: SCHEMA_VERSION,
            step: r.step(),
            t_plus: r.float(),
            dt_plus: r.float(),
            cfl: r.float(),
            max_divergence: r.float(),
            bulk_velocity: r.float(),
            re_tau: r.float(),
            pressure_gradient: r.float(),
            fiber_force_plus: {
                let n = r.len_near(3);
                r.floats(n)
            },
        }),
        Kind::FlowProfiles => {
            let n = r.below(40) as usize;
            let col = |r: &mut Rng| {
                let m = r.len_near(n);
                r.floats(m)
            };
            encode(&FlowProfiles {
                schema_version: SCHEMA_VERSION,
                step: r.step(),
                t_plus: r.float(),
                samples: r.below(100),
                t_plus_span: r.float(),
                re_tau: r.float(),
                bulk_velocity: r.float(),
                y_plus: r.floats(n),
                u_mean: col(r),
                u_rms: col(r),
                v_rms: col(r),
                w_rms: col(r),
                uv: col(r),
                omega_z_mean: col(r),
                omega_x_rms: col(r),
                omega_y_rms: col(r),
                omega_z_rms: col(r),
            })
        }
        Kind::FlowSlice => {
            let (nu, nv) = (r.below(8) as usize, r.below(8) as usize);
            let m = r.len_near(nu * nv);
            // half the time increasing coordinates, so slices also pass the checks
            let mut coords = |n: usize| {
                let mut c = r.floats(n);
                if r.below(2) == 0 {
                    c.sort_by(f64::total_cmp);
                }
                c
            };
            let (u_plus, v_plus) = (coords(nu), coords(nv));
            encode(&FlowSlice {
                schema_version: SCHEMA_VERSION,
                step: r.step(),
                t_plus: r.float(),
                name: "streaks".into(),
                quantity: "u_fluct_plus".into(),
                origin: r.floats(3),
                axis_u: vec![1.0, 0.0, 0.0],
                axis_v: vec![0.0, 0.0, 1.0],
                u_plus,
                v_plus,
                values: r.floats(m).into_iter().map(|x| x as f32).collect(),
            })
        }
        Kind::FlowSamples => {
            let n = r.below(60) as usize;
            let (a, b) = (r.len_near(3 * n), r.len_near(9 * n));
            let (first_fiber, group_fibers) = r.piece(n);
            encode(&FlowSamples {
                schema_version: SCHEMA_VERSION,
                group: r.name(groups),
                step: r.step(),
                t_plus: r.float(),
                first_fiber,
                group_fibers,
                velocity: r.floats(a),
                velocity_gradient: r.floats(b),
            })
        }
        Kind::FiberGroupState => encode(&state(r, groups)),
        Kind::FiberGroupMetrics => {
            let n = r.below(20) as usize;
            let (a, b, c) = (r.len_near(3 * n), r.len_near(n), r.len_near(n));
            let (first_fiber, group_fibers) = r.piece(n);
            encode(&FiberGroupMetrics {
                schema_version: SCHEMA_VERSION,
                group: r.name(groups),
                step: r.step(),
                t_plus: r.float(),
                first_fiber,
                group_fibers,
                centre_of_mass: r.floats(a),
                z1: r.floats(n),
                sigma2: r.floats(b),
                end_to_end: r.floats(c),
                mean_abs_z1: r.float(),
                mean_sigma2: r.float(),
            })
        }
        Kind::FiberFreeStep => {
            let st = state(r, groups);
            let mut arr = || {
                let n = r.len_near(st.centre.len());
                r.floats(n)
            };
            encode(&FiberFreeStep {
                schema_version: SCHEMA_VERSION,
                start_centre: arr(),
                start_axis: arr(),
                start_normal: arr(),
                centre: arr(),
                axis: arr(),
                normal: arr(),
                velocity: arr(),
                angular_velocity: arr(),
                group: st.group,
                step: st.step,
                t_plus: st.t_plus,
                first_fiber: st.first_fiber,
                group_fibers: st.group_fibers,
                segments_per_fiber: st.segments_per_fiber,
            })
        }
        Kind::FiberContactSolved => {
            let st = state(r, groups);
            let nf = st.segments_per_fiber.len();
            // moved fibres: a random ascending subset, now and then out of order or range
            let mut moved: Vec<u32> = Vec::new();
            for k in 0..nf as u32 {
                if r.chance(2) {
                    moved.push(if r.chance(30) { k + 7 } else { k });
                }
            }
            let moved_segments: Vec<u32> = moved
                .iter()
                .map(|&k| st.segments_per_fiber.get(k as usize).copied().unwrap_or(1))
                .collect();
            let nseg: usize = moved_segments.iter().map(|&n| n as usize).sum();
            let mut arr = || {
                let n = r.len_near(3 * nseg);
                r.floats(n)
            };
            let (centre, axis, normal, velocity, angular_velocity) =
                (arr(), arr(), arr(), arr(), arr());
            let nc = r.below(4) as usize;
            let contact_segment: Vec<u32> = (0..nc as u32).collect();
            let nforce = r.len_near(3 * nc);
            let ncount = r.len_near(nc);
            encode(&FiberContactSolved {
                schema_version: SCHEMA_VERSION,
                group: st.group,
                step: st.step,
                t_plus: st.t_plus,
                first_fiber: st.first_fiber,
                group_fibers: st.group_fibers,
                fibers: nf as u32,
                moved,
                moved_segments,
                centre,
                axis,
                normal,
                velocity,
                angular_velocity,
                contact_segment,
                contact_force: r.floats(nforce),
                contacts: vec![1; ncount],
                worst_gap: r.float(),
                sweeps: r.below(10) as u32,
                pairs: r.below(10) as u32,
                candidates: r.below(10) as u32,
                locked: Vec::new(),
                frozen: Vec::new(),
            })
        }
        _ => encode(&Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: r.name(groups),
            state: Lifecycle::ALL[r.below(8) as usize],
            step: r.step(),
            dropped: r.next_u64(),
        }),
    }
}

/// A payload of `kind` that always breaks a rule a receiver checks: inconsistent
/// arrays, a non-finite value, an unknown lifecycle state, a name outside the run, or a
/// step beyond any run (≥ 2^40).
pub fn nonsense_payload(kind: Kind, r: &mut Rng, groups: &[String]) -> Vec<u8> {
    loop {
        let b = random_payload(kind, r, groups);
        let broken = match crate::sanity::check_payload(kind, &b) {
            Err(_) => true,
            Ok(stamp) => {
                stamp.step.is_some_and(|k| k >= 1 << 40)
                    || stamp
                        .owner
                        .as_ref()
                        .is_some_and(|o| o.is_empty() || o.starts_with("intruder"))
            }
        };
        // an announcement that passes its checks still names another run ("" or
        // "intruder…" ids, a random digest): receivers compare both
        let announce_ok = kind == Kind::RunAnnouncement;
        if broken || announce_ok {
            return b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sanity::{check_payload, Sane};

    /// 10^5 random messages of every type through the checks: none panics, and every
    /// accepted state can be walked fibre by fibre with its own counts (what the recorder's
    /// PointCloud2, the analysis and the viewer do) without leaving its arrays.
    #[test]
    fn checks_survive_random_structured_messages() {
        let groups = vec!["case1".to_string(), "case2".to_string()];
        let mut r = Rng::new(7);
        let mut accepted = [0u32; KINDS.len()];
        for i in 0..100_000 {
            let t = KINDS[i % KINDS.len()];
            let b = random_payload(t, &mut r, &groups);
            if check_payload(t, &b).is_ok() {
                accepted[i % KINDS.len()] += 1;
                if t == Kind::FiberGroupState {
                    let s: FiberGroupState = crate::decode(&b).unwrap();
                    assert!(s.check().is_ok());
                    let mut seg = 0usize;
                    for (f, &n) in s.segments_per_fiber.iter().enumerate() {
                        let _ = (s.segment_length[f], s.layer[f], s.diameter[f]);
                        for i in seg..seg + n as usize {
                            let _ = (s.centre[3 * i + 2], s.axis[3 * i + 2]);
                            let _ = (s.velocity[3 * i + 2], s.angular_velocity[3 * i + 2]);
                        }
                        seg += n as usize;
                    }
                }
            }
            // a truncated copy never passes as the full message
            if b.len() > 8 {
                let cut = &b[..b.len() - 1 - (i % 7)];
                let _ = check_payload(t, cut);
            }
        }
        // the generator reaches both sides of every check
        for (t, n) in KINDS.iter().zip(accepted) {
            assert!(
                n > 100 && (n as usize) < 100_000 / KINDS.len(),
                "{t}: {n} of {} accepted",
                100_000 / KINDS.len()
            );
        }
    }

    #[test]
    fn nonsense_is_always_refused_or_foreign() {
        let groups = vec!["case1".to_string()];
        let mut r = Rng::new(3);
        for i in 0..20_000 {
            let t = KINDS[i % KINDS.len()];
            let b = nonsense_payload(t, &mut r, &groups);
            if let Ok(stamp) = check_payload(t, &b) {
                let foreign = stamp.step.is_some_and(|k| k >= 1 << 40)
                    || stamp
                        .owner
                        .as_ref()
                        .is_some_and(|o| o.is_empty() || o.starts_with("intruder"))
                    || t == Kind::RunAnnouncement;
                assert!(foreign, "{t} passed as sensible");
            }
        }
    }

    /// The one-pass finiteness check gives the early-exit search's verdict, and the error
    /// names the first value that is not finite: 20,000 random arrays of 0..300 values
    /// (normal, subnormal, ±MAX, ±0) with NaN, ±∞ or nothing planted at random places.
    #[test]
    fn one_pass_finiteness_agrees_with_the_search() {
        let mut r = Rng::new(11);
        let specials = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            -f64::MAX,
            f64::MIN_POSITIVE / 8.0,
            -0.0,
        ];
        let mut bad_seen = 0;
        for _ in 0..20_000 {
            let n = r.below(300) as usize;
            let mut xs: Vec<f64> = (0..n).map(|_| (r.float() - 0.5) * 1e6).collect();
            for _ in 0..r.below(3) {
                if n > 0 {
                    let i = r.below(n as u64) as usize;
                    xs[i] = specials[r.below(specials.len() as u64) as usize];
                }
            }
            let first_bad = xs.iter().position(|x| !x.is_finite());
            assert_eq!(
                crate::sanity::all_finite(xs.iter().copied()),
                first_bad.is_none()
            );
            match (crate::sanity::finite("xs", &xs), first_bad) {
                (Ok(()), None) => {}
                (Err(e), Some(i)) => {
                    assert_eq!(e, format!("xs[{i}] is not finite"));
                    bad_seen += 1;
                }
                (got, want) => panic!("{got:?} for first non-finite value {want:?}"),
            }
        }
        assert!(bad_seen > 1000, "too few arrays carried a non-finite value");
    }
}
