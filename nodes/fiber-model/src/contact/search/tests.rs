use super::*;
use crate::contact::geometry::closest_points;

/// The cell coordinates fold without the library remainder and truncate instead of
/// `floor`: the same bits and the same cells as the library's, inside the box, one
/// period either side, on the edges and far away.
#[test]
fn folding_is_the_remainder_and_cells_are_the_floor() {
    let period = 942.477_796_076_938;
    let mut xs = vec![
        0.0,
        -0.0,
        period,
        -period,
        2.0 * period,
        -1e-300,
        1e-300,
        period - 1e-13,
        -period + 1e-13,
        5.5 * period,
        -7.25 * period,
        f64::NAN,
        f64::INFINITY,
    ];
    let mut rng = Rng(7);
    for _ in 0..100_000 {
        xs.push((rng.next() * 6.0 - 3.0) * period);
    }
    for &x in &xs {
        let (got, want) = (fold(x, period), x.rem_euclid(period));
        assert!(
            got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
            "{x}: {got} against {want}"
        );
    }
    let cells = CellList {
        dims: [283, 91, 141],
        side: [period / 283.0, 3.3, 471.2 / 141.0],
        lo: [0.0, -150.0, 0.0],
        periodic: [true, false, true],
        ..Default::default()
    };
    for w in xs.windows(3) {
        let r = Vector3::new(w[0], w[1] / period * 200.0, w[2] / 2.0);
        let want: [i64; 3] = std::array::from_fn(|k| {
            let x = if cells.periodic[k] {
                r[k].rem_euclid(cells.side[k] * cells.dims[k] as f64)
            } else {
                r[k] - cells.lo[k]
            };
            ((x / cells.side[k]).floor() as i64).clamp(0, cells.dims[k] as i64 - 1)
        });
        assert_eq!(cells.coords(&r), want, "{r:?}");
    }
}
use crate::contact::geometry;

/// A small deterministic generator (xorshift64*), uniform in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn vector(&mut self, scale: f64) -> Vector3<f64> {
        Vector3::new(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5) * 2.0 * scale
    }
}

const PERIOD: [Option<f64>; 3] = [Some(24.0), None, Some(18.0)];

/// `n` seven-segment fibres (l = 3, d = 0.8) at random in a box periodic in x and z,
/// and the same fibres after a step: each moved by the shift `motion` gives it (from
/// its index and centre) and each segment jittered and turned by up to the turn it
/// gives.
fn moved_fibers(
    seed: u64,
    n: usize,
    motion: impl Fn(usize, &Vector3<f64>, &mut Rng) -> (Vector3<f64>, f64),
) -> (Vec<Fiber>, Vec<Fiber>) {
    let mut rng = Rng(seed);
    let mut before = Vec::new();
    let mut after = Vec::new();
    for k in 0..n {
        let centre = Vector3::new(
            24.0 * rng.next(),
            12.0 * rng.next() - 6.0,
            18.0 * rng.next(),
        );
        let axis = rng.vector(1.0).normalize();
        let f = Fiber::straight(centre, axis, &[3.0; 7], &[0.8; 7], 1000.0).unwrap();
        let mut g = f.clone();
        let (shift, turn) = motion(k, &centre, &mut rng);
        for s in g.segments.iter_mut() {
            s.r += shift + rng.vector(0.05);
            s.z = (s.z + rng.vector(turn)).normalize();
        }
        before.push(f);
        after.push(g);
    }
    (before, after)
}

/// 60 fibres: most moved by up to 0.3, every tenth by up to 4 (a large spread of
/// displacements), each segment turned by up to 0.1 (bending).
fn start_and_end(seed: u64) -> (Vec<Fiber>, Vec<Fiber>) {
    moved_fibers(seed, 60, |k, _, rng| {
        (rng.vector(if k % 10 == 0 { 4.0 } else { 0.3 }), 0.1)
    })
}

/// 150 fibres moved by a mean flow along x that grows across y (from 0 to 6 over the
/// box's 12, as near a wall) and by up to 0.15 along each direction besides; with
/// `thrown`, every 25th fibre is instead thrown by up to 6 along each direction and its
/// segments turned far (wild fibres, searched around on their own).
fn in_a_mean_flow(seed: u64, thrown: bool) -> (Vec<Fiber>, Vec<Fiber>) {
    moved_fibers(seed, 150, |k, centre, rng| {
        if thrown && k.is_multiple_of(25) {
            (rng.vector(6.0), 1.0)
        } else {
            let flow = Vector3::new(0.5 * (centre.y + 6.0), 0.0, 0.0);
            (flow + rng.vector(0.15), 0.1)
        }
    })
}

fn same(a: &[Candidate], b: &[Candidate]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            x.a == y.a
                && x.b == y.b
                && x.shift == y.shift
                && x.normal0 == y.normal0
                && x.reach.to_bits() == y.reach.to_bits()
        })
}

/// The step's search over `before` → `after`, what its scan finds and what a test of
/// every pair keeps.
fn scanned(before: &[Fiber], after: &[Fiber]) -> (Search, Vec<Candidate>, Vec<Candidate>) {
    let s = Slices::new(before, after);
    let search = Search::new(&s, &PERIOD, 0.0);
    let found = search.pairs(&s);
    let expected = all_pairs(&s, &search);
    (search, found, expected)
}

/// Each trial k's pair of fibres 2k and 2k + 1 is among `expected`.
fn assert_every_trial_kept(expected: &[Candidate], trials: usize) {
    for k in 0..trials {
        assert!(
            expected
                .iter()
                .any(|c| c.a == (2 * k, 0) && c.b == (2 * k + 1, 0)),
            "the exact test dropped trial {k}"
        );
    }
}

fn assert_found(seed: u64, found: &[Candidate], expected: &[Candidate]) {
    assert!(
        same(found, expected),
        "seed {seed}: {} found, {} expected",
        found.len(),
        expected.len()
    );
}

/// Every pair of segments of different fibres, and of non-adjacent segments of one
/// fibre, by [`pair`] alone (no cell list).
fn all_pairs<S: Segments>(s: &S, search: &Search) -> Vec<Candidate> {
    let offsets = s.offsets();
    let e: Vec<Entry> = (0..offsets.len() - 1)
        .flat_map(|k| (0..offsets[k + 1] - offsets[k]).map(move |i| (k, i)))
        .map(|(k, i)| Entry::of(s, k, i, search.pad))
        .collect();
    let mut out = Vec::new();
    for (n, ea) in e.iter().enumerate() {
        for eb in &e[n + 1..] {
            out.extend(pair(ea, eb, f64::INFINITY, &search.period));
        }
    }
    out
}

/// Every pair of segments (of different fibres, or non-adjacent ones of one fibre),
/// one of them `moved`, that may have
/// come within reach between `was` (the start of the step) and `now` (skin: their
/// relative motion and turns) and overlaps now on the side it was on in `was`.
fn all_overlaps(was: &[Fiber], now: &[Fiber], moved: &[usize]) -> Vec<Candidate> {
    all_overlaps_in(was, now, moved, &PERIOD)
}

/// [`all_overlaps`] in a box of `period`.
fn all_overlaps_in(
    was: &[Fiber],
    now: &[Fiber],
    moved: &[usize],
    period: &[Option<f64>; 3],
) -> Vec<Candidate> {
    let segs: Vec<(usize, usize)> = (0..now.len())
        .flat_map(|k| (0..now[k].len()).map(move |i| (k, i)))
        .collect();
    let pose = |f: &[Fiber], k: usize, i: usize| {
        let (s, p) = (&f[k].segments[i], &f[k].props[i]);
        (s.r, s.z, 0.5 * p.shape.length, 0.5 * p.shape.diameter)
    };
    let mut out = Vec::new();
    for (n, &(ka, ia)) in segs.iter().enumerate() {
        for &(kb, ib) in &segs[n + 1..] {
            if (ka == kb && ia.abs_diff(ib) < 2) || !(moved.contains(&ka) || moved.contains(&kb)) {
                continue;
            }
            out.extend(fresh_pair(
                (ka, ia),
                (pose(was, ka, ia), pose(now, ka, ia)),
                (kb, ib),
                (pose(was, kb, ib), pose(now, kb, ib)),
                period,
            ));
        }
    }
    out
}

/// A pair pushed through each other keeps its side at the start (an overlap deeper
/// than d); a pair that was far apart and only turned into touch takes its side where
/// it is now.
#[test]
fn a_pair_pushed_through_keeps_its_side_and_one_that_turned_takes_its_own() {
    let seg = |r: Vector3<f64>, z: Vector3<f64>| (r, z, 1.5, 0.116);
    // b along z at the origin; a along x, 0.3 above, pushed to 0.1 below
    let b = seg(Vector3::zeros(), Vector3::z());
    let c = fresh_pair(
        (0, 0),
        (
            seg(Vector3::new(0.0, 0.3, 0.0), Vector3::x()),
            seg(Vector3::new(0.0, -0.1, 0.0), Vector3::x()),
        ),
        (1, 0),
        (b, b),
        &[None; 3],
    )
    .unwrap();
    assert!(c.normal0.y > 0.99, "{:?}", c.normal0);
    // a along x, its end 2 to the side of b and 1 below, moved so its end meets b from
    // above: never closer than 0.17 on the way (the side at the start, from b to a's
    // end, points down)
    let c = fresh_pair(
        (0, 0),
        (
            seg(Vector3::new(3.5, -1.0, 0.0), Vector3::x()),
            seg(Vector3::new(1.5, 0.2, 0.0), Vector3::x()),
        ),
        (1, 0),
        (b, b),
        &[None; 3],
    )
    .unwrap();
    assert!(c.normal0.y > 0.99, "{:?}", c.normal0);
}

/// A segment pushed fast through another within one step (40 d across, ending 0.6 d
/// on the far side) passes it between any 17 evenly spaced moments of its way; the
/// way is looked at often enough for its motion, so the pair keeps its start side.
#[test]
fn a_pair_pushed_fast_through_keeps_its_side_however_far_it_moved() {
    let d = 0.232;
    let seg = |r: Vector3<f64>, z: Vector3<f64>| (r, z, 1.5, 0.5 * d);
    let b = seg(Vector3::zeros(), Vector3::z());
    let (from, to) = (40.0 * d, -0.6 * d);
    // at 17 moments the closest is 15/16 of the way: still above half a diameter
    let at = |t: f64| from + (to - from) * t;
    assert!(at(15.0 / 16.0) > 0.5 * d && at(1.0).abs() > 0.5 * d);
    let c = fresh_pair(
        (0, 0),
        (
            seg(Vector3::new(0.0, from, 0.0), Vector3::x()),
            seg(Vector3::new(0.0, to, 0.0), Vector3::x()),
        ),
        (1, 0),
        (b, b),
        &[None; 3],
    )
    .unwrap();
    assert!(c.normal0.y > 0.99, "took the far side: {:?}", c.normal0);
}

/// Pairs placed just within reach (centre-lines 10⁻⁶ of a contact distance closer than
/// it) in the fine-grid box, where single precision rounds a coordinate by up to
/// 3 × 10⁻⁵ (a third of them by its far x face, a third by its far z face), crossing,
/// skew and parallel, at rest and moving together by up to 3 wall units: the scan's
/// single-precision tests keep every one, as the exact test does.
#[test]
fn single_precision_tests_keep_pairs_just_within_reach() {
    let period = [Some(942.48), None, Some(471.24)];
    let (half, d) = (1.5, 0.232);
    let mut rng = Rng(7);
    let (mut before, mut after) = (Vec::new(), Vec::new());
    let trials = 400;
    for k in 0..trials {
        let ca = Vector3::new(
            if k % 3 == 0 {
                942.47
            } else {
                942.48 * rng.next()
            },
            290.0 * (rng.next() - 0.5),
            if k % 3 == 1 {
                471.235
            } else {
                471.24 * rng.next()
            },
        );
        let za = rng.vector(1.0).normalize();
        let p = ca + za * (0.9 * half * (2.0 * rng.next() - 1.0));
        // the common normal, and b's axis across it: parallel to a's every fourth time
        let across = za.cross(&rng.vector(1.0)).normalize();
        let angle = std::f64::consts::PI * rng.next();
        let zb = if k % 4 == 0 {
            za
        } else {
            (za * angle.cos() + across.cross(&za) * angle.sin()).normalize()
        };
        let q = p + across * (d * (1.0 - 1e-6));
        let cb = q - zb * (0.9 * half * (2.0 * rng.next() - 1.0));
        let shift = if k % 2 == 0 {
            Vector3::zeros()
        } else {
            rng.vector(3.0)
        };
        for (c, z) in [(ca, za), (cb, zb)] {
            let f = Fiber::straight(c, z, &[2.0 * half], &[d], 1000.0).unwrap();
            let mut g = f.clone();
            g.segments[0].r += shift;
            before.push(f);
            after.push(g);
        }
    }
    let s = Slices::new(&before, &after);
    let search = Search::new(&s, &period, 0.0);
    let found = search.pairs(&s);
    let expected = all_pairs(&s, &search);
    assert_every_trial_kept(&expected, trials);
    assert!(
        same(&found, &expected),
        "{} found, {} expected",
        found.len(),
        expected.len()
    );
}

#[test]
fn the_cell_list_finds_every_pair_the_exact_test_keeps() {
    for seed in [1, 2, 3] {
        let (before, after) = start_and_end(seed);
        let (search, found, expected) = scanned(&before, &after);
        // the case is a real one: many pairs, some across a periodic boundary, and
        // displacements spread far wider than a diameter
        assert!(expected.len() > 100, "{} pairs", expected.len());
        assert!(expected.iter().any(|c| c.shift != Vector3::zeros()));
        assert!(search.spread > 2.0, "spread {}", search.spread);
        assert_found(seed, &found, &expected);
    }
}

/// In a mean flow along x the cells are narrower across the flow than along it, and
/// the scan still finds every pair the exact test keeps, among them pairs whose
/// displacements differ by more than their contact distance.
#[test]
fn cells_narrower_across_a_mean_flow_find_every_pair() {
    for seed in [7, 8, 9] {
        let (before, after) = in_a_mean_flow(seed, false);
        let (search, found, expected) = scanned(&before, &after);
        assert!(expected.len() > 100, "{} pairs", expected.len());
        let apart = |c: &Candidate| {
            (after[c.a.0].segments[c.a.1].r - before[c.a.0].segments[c.a.1].r)
                - (after[c.b.0].segments[c.b.1].r - before[c.b.0].segments[c.b.1].r)
        };
        assert!(expected.iter().any(|c| apart(c).x.abs() > 1.0));
        let along = search.spread_along;
        assert!(along.x > 2.5 && along.y < 0.3 && along.z < 0.3, "{along:?}");
        assert!(search.wild.is_empty());
        let side = search.cells.side;
        assert!(
            side[0] > side[1] + 2.0 && side[0] > side[2] + 2.0,
            "{side:?}"
        );
        assert_found(seed, &found, &expected);
    }
}

/// Fibres thrown about (displaced and turned far beyond the others) are searched
/// around on their own: the cells keep the size the others need, and the scan and
/// the wild fibres' search together find every pair the exact test keeps, among them
/// pairs of a wild fibre beyond the cells' reach and pairs of two wild fibres' segments.
#[test]
fn wild_fibers_are_searched_on_their_own_and_every_pair_is_found() {
    for seed in [13, 14, 15, 16] {
        let (before, after) = in_a_mean_flow(seed, true);
        let s = Slices::new(&before, &after);
        let search = Search::new(&s, &PERIOD, 0.0);
        assert_eq!(search.wild, [0, 25, 50, 75, 100, 125]);
        assert!(search.bulk_most_turn < 0.5 * search.most_turn);
        assert!(
            search.bulk_spread_along.y < 0.3 && search.spread_along.y > 1.0,
            "{:?} {:?}",
            search.bulk_spread_along,
            search.spread_along
        );
        let side = search.cells.side;
        assert!(side[1] < 5.0 && side[2] < 5.0, "{side:?}");
        let found = search.pairs(&s);
        let expected = all_pairs(&s, &search);
        let wild = |c: &Candidate| c.a.0.is_multiple_of(25) || c.b.0.is_multiple_of(25);
        assert!(expected.iter().filter(|c| wild(c)).count() > 10);
        assert_found(seed, &found, &expected);
    }
}

/// After a round of corrections, the search around the moved fibres finds exactly the
/// overlaps a test of every pair finds, each on the side it was on at the start of
/// the step (some corrections here push fibres through others), also in a mean flow.
#[test]
fn the_search_around_moved_fibers_finds_every_overlap_they_make() {
    let cases = [4, 5, 6].map(|seed| (seed, start_and_end(seed)));
    // and in a mean flow, where the step's cells are narrower across the flow
    let sheared = [10, 11, 12].map(|seed| (seed, in_a_mean_flow(seed, seed == 12)));
    for (seed, (before, after)) in cases.into_iter().chain(sheared) {
        let s = Slices::new(&before, &after);
        let search = Search::new(&s, &PERIOD, 0.0);
        // a third of the fibres corrected in earlier rounds (pushed by up to 1.5),
        // half of those again in this round (pushed by up to 1, and turned)
        let mut rng = Rng(seed + 100);
        let mut was = after.clone();
        let corrected: Vec<bool> = (0..was.len()).map(|k| k % 3 == 0).collect();
        for (k, f) in was.iter_mut().enumerate() {
            if corrected[k] {
                let push = rng.vector(1.5);
                f.segments.iter_mut().for_each(|s| s.r += push);
            }
        }
        let moved: Vec<usize> = (0..was.len()).filter(|k| k % 6 == 0).collect();
        let mut now = was.clone();
        for &k in &moved {
            let push = rng.vector(1.0);
            for s in now[k].segments.iter_mut() {
                s.r += push;
                s.z = (s.z + rng.vector(0.05)).normalize();
            }
        }
        let found = search.around(&s, &now, &before, &corrected, &moved);
        // every fibre not corrected is where the free step left it
        let now: Vec<Fiber> = (0..now.len())
            .map(|k| {
                if corrected[k] {
                    now[k].clone()
                } else {
                    after[k].clone()
                }
            })
            .collect();
        let mut expected = all_overlaps(&before, &now, &moved);
        expected.sort_by_key(|c| (c.a, c.b));
        assert!(expected.len() > 10, "{} overlaps", expected.len());
        // some of them crossed in the round: deeper than a diameter on their old side
        assert!(
            expected.iter().any(|c| geometry(&now, c).2 < -c.reach),
            "no pair crossed"
        );
        assert_found(seed, &found, &expected);
    }
}

/// The search after a round in single precision, at its edge: a corrected fibre
/// pushed to 2 × 10⁻⁶ of a contact distance inside one that the free step left where
/// it is (crossing, skew, parallel, and end to end on one line, where the centres are
/// as far apart as the first test allows; an overlap counts from 10⁻⁶), in the fine-grid
/// box, by its far x and z faces where single precision rounds a coordinate by up to
/// 3 × 10⁻⁵, the unmoved one at rest or moved by up to 3 wall units in the step: every
/// such overlap is found, as a test of every pair finds it. (The segments' own
/// margins, 10⁻⁴ of their sizes, exceed the rounding there: a first test made 3 × 10⁻⁴
/// tighter lost the 60 end-to-end pairs, one 10⁻⁵ tighter none.)
#[test]
fn the_search_around_keeps_overlaps_just_within_reach_in_single_precision() {
    let period = [Some(942.48), None, Some(471.24)];
    let (xp, zp) = (period[0].unwrap_or(0.0), period[2].unwrap_or(0.0));
    let (half, d) = (1.5, 0.232);
    let mut rng = Rng(17);
    let (mut before, mut after, mut now) = (Vec::new(), Vec::new(), Vec::new());
    let trials = 300;
    for k in 0..trials {
        // the unmoved fibre: where the free step left it
        let ca = Vector3::new(
            if k % 3 == 0 {
                xp - 0.01
            } else {
                xp * rng.next()
            },
            290.0 * (rng.next() - 0.5),
            if k % 3 == 1 {
                zp - 0.005
            } else {
                zp * rng.next()
            },
        );
        let za = rng.vector(1.0).normalize();
        let shift = if k % 2 == 0 {
            Vector3::zeros()
        } else {
            rng.vector(3.0)
        };
        let a0 = Fiber::straight(ca, za, &[2.0 * half], &[d], 1000.0).unwrap();
        let mut a1 = a0.clone();
        a1.segments[0].r += shift;
        // the corrected one, now 10⁻⁶ d inside it
        let p = a1.segments[0].r + za * (0.9 * half * (2.0 * rng.next() - 1.0));
        let across = za.cross(&rng.vector(1.0)).normalize();
        let angle = std::f64::consts::PI * rng.next();
        let zb = if k % 4 == 0 {
            za
        } else {
            (za * angle.cos() + across.cross(&za) * angle.sin()).normalize()
        };
        let (cb, zb, across) = if k % 5 == 2 {
            // end to end along one line: the centres as far apart as an overlap allows,
            // at the bound of the first single-precision test
            let end = a1.segments[0].r + za * half;
            let q = end + za * (d * (1.0 - 2e-6));
            (q + za * half, za, za)
        } else {
            let q = p + across * (d * (1.0 - 2e-6));
            (q - zb * (0.9 * half * (2.0 * rng.next() - 1.0)), zb, across)
        };
        let b_now = Fiber::straight(cb, zb, &[2.0 * half], &[d], 1000.0).unwrap();
        // it came there from the same side, three contact distances out
        let mut b0 = b_now.clone();
        b0.segments[0].r += across * (3.0 * d);
        before.extend([a0, b0.clone()]);
        after.extend([a1.clone(), b0]);
        now.extend([a1, b_now]);
    }
    let s = Slices::new(&before, &after);
    let search = Search::new(&s, &period, 0.0);
    let corrected: Vec<bool> = (0..now.len()).map(|k| k % 2 == 1).collect();
    let moved: Vec<usize> = (0..now.len()).filter(|k| k % 2 == 1).collect();
    let found = search.around(&s, &now, &before, &corrected, &moved);
    let mut expected = all_overlaps_in(&before, &now, &moved, &period);
    expected.sort_by_key(|c| (c.a, c.b));
    assert_every_trial_kept(&expected, trials);
    assert_found(17, &found, &expected);
}

/// The conditions of [`pair`] are necessary: two segments that come within their
/// contact distance at any moment of the step (centres moving straight, axes turning
/// from start to end) are a candidate pair, whatever their motion.
#[test]
fn a_pair_that_touches_within_the_step_is_a_candidate() {
    let mut rng = Rng(7);
    let (mut touching, mut kept) = (0, 0);
    for _ in 0..20000 {
        let f = |rng: &mut Rng, k: u32| {
            let r0 = rng.vector(2.5);
            let z0 = rng.vector(1.0).normalize();
            let shift = rng.vector(3.0);
            let z1 = (z0 + rng.vector(0.6)).normalize();
            (k, r0, z0, shift, z1)
        };
        let (a, b) = (f(&mut rng, 0), f(&mut rng, 1));
        let (half, radius) = (1.5, 0.116);
        let entry = |(k, r0, z0, shift, z1): (
            u32,
            Vector3<f64>,
            Vector3<f64>,
            Vector3<f64>,
            Vector3<f64>,
        )| Entry {
            start: r0,
            axis: z0,
            shift,
            turn: half * (z1 - z0).norm(),
            half,
            radius,
            fiber: k,
            segment: 0,
        };
        let at = |(_, r0, z0, shift, z1): (
            u32,
            Vector3<f64>,
            Vector3<f64>,
            Vector3<f64>,
            Vector3<f64>,
        ),
                  t: f64| {
            let r = r0 + shift * t;
            let z = (z0 + (z1 - z0) * t).normalize();
            (r - z * half, r + z * half)
        };
        let touches = (0..=200).any(|n| {
            let t = n as f64 / 200.0;
            let ((p0, p1), (q0, q1)) = (at(a, t), at(b, t));
            let (s, u) = closest_points(&p0, &p1, &q0, &q1);
            ((p0 + (p1 - p0) * s) - (q0 + (q1 - q0) * u)).norm() < 2.0 * radius
        });
        let found = pair(&entry(a), &entry(b), f64::INFINITY, &[None; 3]).is_some();
        touching += usize::from(touches);
        kept += usize::from(found);
        assert!(
            !touches || found,
            "a touching pair was not kept: {a:?} {b:?}"
        );
    }
    // many touch, and the test keeps more than those (a bound, not the answer)
    assert!(touching > 500, "{touching} touching");
    assert!(kept > touching, "{kept} kept");
}

/// A fibre whose state went non-finite makes no pairs (every comparison with NaN
/// fails), instead of pairing with every other segment; the others' pairs stay.
#[test]
fn a_fiber_gone_non_finite_makes_no_pairs() {
    let (before, mut after) = start_and_end(1);
    let s = Slices::new(&before, &after);
    let clean = Search::new(&s, &PERIOD, 0.0).pairs(&s);
    after[3].segments[2].r.x = f64::NAN;
    let s = Slices::new(&before, &after);
    let found = Search::new(&s, &PERIOD, 0.0).pairs(&s);
    let without: Vec<Candidate> = clean
        .into_iter()
        .filter(|c| c.a != (3, 2) && c.b != (3, 2))
        .collect();
    assert!(!without.is_empty());
    assert!(
        same(&found, &without),
        "{} found, {} expected",
        found.len(),
        without.len()
    );
}
