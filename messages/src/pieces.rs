//! Sharded groups: a group of F fibres may be integrated by K fibre nodes, shard i owning
//! the contiguous fibres `i·F/K .. (i+1)·F/K`. Each shard publishes its slice on the
//! group's topics (messages say which fibres they cover: `first_fiber`, `group_fibers`)
//! and receives its samples on a topic of its own. Readers put the slices back together
//! with [`Tiles`] and the `merge_*` functions, so a sharded group reads as one group.

use crate::topics::Topics;
use crate::types::{FiberGroupMetrics, FiberGroupState};
use std::collections::BTreeMap;

/// One fibre node's share of a group.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Piece {
    pub group: String,
    /// Shard index and count (0 of 1 for an unsharded group).
    pub index: u32,
    pub shards: u32,
    pub first_fiber: u32,
    pub fibers: u32,
    pub group_fibers: u32,
    /// Segments of the piece's fibres.
    pub segments: usize,
}

impl Piece {
    /// The node that integrates this piece: the group's name, or `<group>.<index>` for a
    /// sharded group.
    pub fn node(&self) -> String {
        node_name(&self.group, self.index, self.shards)
    }

    /// Where the flow node sends this piece's samples.
    pub fn samples_topic(&self, t: &Topics) -> String {
        if self.shards == 1 {
            t.flow_samples(&self.group)
        } else {
            format!("{}/{}", t.flow_samples(&self.group), self.index)
        }
    }
}

pub fn node_name(group: &str, index: u32, shards: u32) -> String {
    if shards == 1 {
        group.to_string()
    } else {
        format!("{group}.{index}")
    }
}

/// First fibre and fibre count of each of `shards` contiguous slices of `fibers`.
pub fn split(fibers: u32, shards: u32) -> Vec<(u32, u32)> {
    let (f, k) = (fibers as u64, shards.max(1) as u64);
    (0..k)
        .map(|i| {
            let (a, b) = (i * f / k, (i + 1) * f / k);
            (a as u32, (b - a) as u32)
        })
        .collect()
}

/// Collects the slices of each (group, step) until they cover the whole group, then hands
/// them over in fibre order. A whole-group message passes straight through.
#[derive(Debug)]
pub struct Tiles<T> {
    /// (group, step) -> (group size, first fibre -> (fibre count, item)).
    open: BTreeMap<(String, u64), Slices<T>>,
}

type Slices<T> = (u32, BTreeMap<u32, (u32, T)>);

impl<T> Default for Tiles<T> {
    fn default() -> Self {
        Self {
            open: BTreeMap::new(),
        }
    }
}

impl<T> Tiles<T> {
    /// Adds fibres `first .. first + n` of a `total`-fibre group at `step`; returns every
    /// slice of that step once they tile `0 .. total`. A slice that disagrees with the
    /// others on the group size restarts the collection; a repeated slice replaces the
    /// earlier one.
    pub fn add(
        &mut self,
        group: &str,
        step: u64,
        first: u32,
        n: u32,
        total: u32,
        item: T,
    ) -> Option<Vec<T>> {
        if first == 0 && n == total {
            self.open.remove(&(group.to_string(), step));
            return Some(vec![item]);
        }
        let key = (group.to_string(), step);
        let entry = self
            .open
            .entry(key.clone())
            .or_insert_with(|| (total, BTreeMap::new()));
        if entry.0 != total {
            *entry = (total, BTreeMap::new());
        }
        entry.1.insert(first, (n, item));
        let mut next = 0u64;
        for (&f, (n, _)) in &entry.1 {
            if f as u64 != next {
                return None;
            }
            next += *n as u64;
        }
        if next != total as u64 {
            return None;
        }
        self.open
            .remove(&key)
            .map(|(_, m)| m.into_values().map(|(_, t)| t).collect())
    }

    /// (group, step) pairs still waiting for slices.
    pub fn incomplete(&self) -> usize {
        self.open.len()
    }
}

/// A group message that may be one slice of a sharded group.
pub trait Slice: Sized {
    /// (group, step, first fibre, fibres, group fibres).
    fn slice(&self) -> (String, u64, u32, u32, u32);
    /// The whole group from its slices in fibre order.
    fn merge(slices: Vec<Self>) -> Option<Self>;
}

impl Slice for FiberGroupState {
    fn slice(&self) -> (String, u64, u32, u32, u32) {
        let n = self.segments_per_fiber.len() as u32;
        (
            self.group.clone(),
            self.step,
            self.first_fiber,
            n,
            self.group_fibers,
        )
    }
    fn merge(slices: Vec<Self>) -> Option<Self> {
        merge_states(slices)
    }
}

impl Slice for FiberGroupMetrics {
    fn slice(&self) -> (String, u64, u32, u32, u32) {
        let n = self.z1.len() as u32;
        (
            self.group.clone(),
            self.step,
            self.first_fiber,
            n,
            self.group_fibers,
        )
    }
    fn merge(slices: Vec<Self>) -> Option<Self> {
        merge_metrics(slices)
    }
}

impl<T: Slice> Tiles<T> {
    /// Adds a message; returns its whole group once the step's slices are all in (at
    /// once for an unsharded group's message).
    pub fn add_slice(&mut self, item: T) -> Option<T> {
        let (group, step, first, n, total) = item.slice();
        self.add(&group, step, first, n, total, item)
            .and_then(T::merge)
    }
}

/// One group state from its slices in fibre order (as [`Tiles::add`] returns them).
pub fn merge_states(mut pieces: Vec<FiberGroupState>) -> Option<FiberGroupState> {
    if pieces.len() <= 1 {
        return pieces.pop();
    }
    let mut it = pieces.into_iter();
    let mut s = it.next()?;
    let segments = |p: &FiberGroupState| {
        p.segments_per_fiber
            .iter()
            .fold(0u32, |a, &n| a.saturating_add(n))
    };
    let mut segments_before = segments(&s);
    for p in it {
        s.contact_segment.extend(
            p.contact_segment
                .iter()
                .map(|&i| i.saturating_add(segments_before)),
        );
        segments_before = segments_before.saturating_add(segments(&p));
        s.segments_per_fiber.extend(p.segments_per_fiber);
        s.segment_length.extend(p.segment_length);
        s.diameter.extend(p.diameter);
        s.density_ratio.extend(p.density_ratio);
        s.layer.extend(p.layer);
        s.centre.extend(p.centre);
        s.axis.extend(p.axis);
        s.velocity.extend(p.velocity);
        s.angular_velocity.extend(p.angular_velocity);
        s.hydro_force.extend(p.hydro_force);
        s.contact_force.extend(p.contact_force);
        s.contacts.extend(p.contacts);
    }
    s.first_fiber = 0;
    Some(s)
}

/// One group's metrics from its slices in fibre order; the means are recomputed over the
/// whole group.
pub fn merge_metrics(mut pieces: Vec<FiberGroupMetrics>) -> Option<FiberGroupMetrics> {
    if pieces.len() <= 1 {
        return pieces.pop();
    }
    let mut it = pieces.into_iter();
    let mut m = it.next()?;
    for p in it {
        m.centre_of_mass.extend(p.centre_of_mass);
        m.z1.extend(p.z1);
        m.sigma2.extend(p.sigma2);
        m.end_to_end.extend(p.end_to_end);
    }
    let n = m.z1.len().max(1) as f64;
    m.mean_abs_z1 = m.z1.iter().map(|z| z.abs()).sum::<f64>() / n;
    m.mean_sigma2 = m.sigma2.iter().sum::<f64>() / n;
    m.first_fiber = 0;
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_is_contiguous_and_complete() {
        for (f, k) in [(10u32, 3u32), (50, 1), (7, 7), (60_000, 4)] {
            let s = split(f, k);
            assert_eq!(s.len(), k as usize);
            let mut next = 0;
            for (a, n) in &s {
                assert_eq!(*a, next);
                assert!(*n >= f / k && *n <= f / k + 1);
                next += n;
            }
            assert_eq!(next, f);
        }
    }

    /// Slices in any arrival order come back complete and in fibre order; gaps, overlaps
    /// or another group size do not complete a step.
    #[test]
    fn tiles_complete_only_when_the_group_is_covered() {
        let mut t = Tiles::default();
        assert_eq!(t.add("g", 1, 6, 4, 10, "c"), None);
        assert_eq!(t.add("g", 1, 0, 3, 10, "a"), None);
        assert_eq!(t.add("g", 2, 0, 10, 10, "whole"), Some(vec!["whole"]));
        assert_eq!(t.add("g", 1, 3, 3, 10, "b"), Some(vec!["a", "b", "c"]));
        assert_eq!(t.incomplete(), 0);
        // an overlap (0..5 and 3..10) is not a tiling
        assert_eq!(t.add("g", 3, 0, 5, 10, "x"), None);
        assert_eq!(t.add("g", 3, 3, 7, 10, "y"), None);
        // a slice of another group size starts over
        assert_eq!(t.add("g", 3, 0, 3, 9, "p"), None);
        assert_eq!(t.add("g", 3, 3, 6, 9, "q"), Some(vec!["p", "q"]));
    }

    /// The contact arrays of a group's slices merge with each slice's segment indices
    /// moved past the segments of the slices before it.
    #[test]
    fn merged_states_number_contact_segments_over_the_whole_group() {
        let piece = |first: u32, spf: Vec<u32>, touched: Vec<u32>| {
            let n: u32 = spf.iter().sum();
            FiberGroupState {
                schema_version: crate::SCHEMA_VERSION,
                group: "g".into(),
                first_fiber: first,
                group_fibers: 3,
                centre: vec![0.0; 3 * n as usize],
                contact_force: touched.iter().flat_map(|&i| [i as f64, 0.0, 0.0]).collect(),
                contacts: vec![1; touched.len()],
                contact_segment: touched,
                segments_per_fiber: spf,
                ..Default::default()
            }
        };
        let whole = merge_states(vec![
            piece(0, vec![7], vec![2, 6]),
            piece(1, vec![5, 7], vec![0, 11]),
        ])
        .expect("merged");
        assert_eq!(whole.contact_segment, vec![2, 6, 7, 18]);
        assert_eq!(
            whole
                .contact_force
                .iter()
                .step_by(3)
                .copied()
                .collect::<Vec<_>>(),
            vec![2.0, 6.0, 0.0, 11.0]
        );
        assert_eq!(whole.contacts, vec![1; 4]);
    }

    /// Two slices of a 3-fibre group, in either arrival order, merge into the whole
    /// group's metrics with the means taken over all three fibres.
    #[test]
    fn add_slice_merges_metrics_over_the_whole_group() {
        let m = |first: u32, z1: Vec<f64>| FiberGroupMetrics {
            schema_version: crate::SCHEMA_VERSION,
            group: "g".into(),
            step: 4,
            t_plus: 1.0,
            first_fiber: first,
            group_fibers: 3,
            centre_of_mass: vec![first as f64; 3 * z1.len()],
            sigma2: z1.iter().map(|z| 2.0 * z).collect(),
            end_to_end: vec![1.0; z1.len()],
            mean_abs_z1: 0.0,
            mean_sigma2: 0.0,
            z1,
        };
        let mut t = Tiles::default();
        assert!(t.add_slice(m(1, vec![-0.5, 1.0])).is_none());
        let w = t.add_slice(m(0, vec![0.5])).expect("complete");
        assert_eq!(w.z1, vec![0.5, -0.5, 1.0]);
        assert_eq!(
            w.centre_of_mass,
            vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
        );
        assert!((w.mean_abs_z1 - 2.0 / 3.0).abs() < 1e-15);
        assert!((w.mean_sigma2 - 2.0 / 3.0).abs() < 1e-15);
        assert_eq!(w.first_fiber, 0);
    }
}
