//! CDR of the bulk messages (FlowSamples, FiberGroupState, FiberGroupMetrics) written and read field by
//! field, each number array copied as a whole: the same bytes as the serde path (tests
//! below), without its per-element calls, its size pre-pass and the separate layout walk.
//! At 6 × 10⁴ fibres the serde path and the walk were ≈ 16% of the machine's CPU.
//!
//! CDR (little-endian, XCDR1 as ROS 2 writes it): after the 4-byte encapsulation header,
//! each primitive is aligned to its own size relative to the first byte after the header;
//! a sequence is a u32 count then its elements; a string is a u32 length including a
//! trailing NUL, then the bytes and the NUL.
//!
//! Size: writer and reader of three message types kept side by side, so that each field's
//! order and alignment is visibly the same in both directions (and as the `.msg` files).

use crate::types::{FiberGroupMetrics, FiberGroupState, FlowSamples};
use std::mem::MaybeUninit;

/// The fields every group message (FlowSamples, FiberGroupState, FiberGroupMetrics) starts
/// with, in wire order.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct GroupHeader {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    pub first_fiber: u32,
    pub group_fibers: u32,
}

/// The CDR little-endian encapsulation header.
const HEADER: [u8; 4] = [0, 1, 0, 0];

/// Where a [`Writer`] puts its bytes: a growing buffer, a slice sized up front (e.g. a
/// transport's loaned shared memory), or nowhere (counting the length).
pub(crate) trait Sink {
    /// Bytes written so far, the encapsulation header included.
    fn pos(&self) -> usize;
    fn bytes(&mut self, b: &[u8]);
    fn zeros(&mut self, n: usize);
    /// Each value as 4 little-endian bytes.
    fn u32s(&mut self, v: &[u32]);
    /// Each value as 8 little-endian bytes.
    fn f64s(&mut self, v: &[f64]);
}

impl Sink for Vec<u8> {
    fn pos(&self) -> usize {
        self.len()
    }
    fn bytes(&mut self, b: &[u8]) {
        self.extend_from_slice(b);
    }
    fn zeros(&mut self, n: usize) {
        self.resize(self.len() + n, 0);
    }
    fn u32s(&mut self, v: &[u32]) {
        let from = self.len();
        self.resize(from + 4 * v.len(), 0);
        put_u32s(&mut self[from..], v);
    }
    fn f64s(&mut self, v: &[f64]) {
        let from = self.len();
        self.resize(from + 8 * v.len(), 0);
        put_f64s(&mut self[from..], v);
    }
}

fn put_u32s(out: &mut [u8], v: &[u32]) {
    for (o, x) in out.chunks_exact_mut(4).zip(v) {
        o.copy_from_slice(&x.to_le_bytes());
    }
}

fn put_f64s(out: &mut [u8], v: &[f64]) {
    for (o, x) in out.chunks_exact_mut(8).zip(v) {
        o.copy_from_slice(&x.to_le_bytes());
    }
}

/// Counts the bytes a message takes.
#[derive(Default)]
pub(crate) struct Count(usize);

impl Sink for Count {
    fn pos(&self) -> usize {
        self.0
    }
    fn bytes(&mut self, b: &[u8]) {
        self.0 += b.len();
    }
    fn zeros(&mut self, n: usize) {
        self.0 += n;
    }
    fn u32s(&mut self, v: &[u32]) {
        self.0 += 4 * v.len();
    }
    fn f64s(&mut self, v: &[f64]) {
        self.0 += 8 * v.len();
    }
}

/// Writes into a slice, initialised or not; what does not fit is counted, not written
/// ([`Fill::exact`] says whether the message filled the slice exactly). The writes are
/// consecutive from the slice's start, so a slice filled exactly has every byte written.
pub(crate) struct Fill<'a> {
    out: &'a mut [MaybeUninit<u8>],
    pos: usize,
}

impl<'a> Fill<'a> {
    pub(crate) fn new(out: &'a mut [u8]) -> Self {
        // SAFETY: a `Fill` only ever writes initialised bytes into `out`, so the `[u8]` it
        // borrows from stays initialised
        let out = unsafe { &mut *(out as *mut [u8] as *mut [MaybeUninit<u8>]) };
        Self { out, pos: 0 }
    }

    /// A slice not initialised yet (e.g. a transport's freshly loaned memory).
    pub(crate) fn uninit(out: &'a mut [MaybeUninit<u8>]) -> Self {
        Self { out, pos: 0 }
    }

    /// The next `n` bytes of the slice (None once past its end); advances either way.
    fn next(&mut self, n: usize) -> Option<&mut [MaybeUninit<u8>]> {
        let from = self.pos;
        self.pos += n;
        self.out.get_mut(from..from + n)
    }

    pub(crate) fn exact(&self) -> bool {
        self.pos == self.out.len()
    }

    /// The slice, initialised, if the message filled it exactly.
    pub(crate) fn finish(self) -> Option<&'a mut [u8]> {
        if !self.exact() {
            return None;
        }
        // SAFETY: `exact` means the writes, each a whole in-bounds range following the one
        // before from index 0 (`next` never goes back), covered every byte of `out`
        Some(unsafe { &mut *(self.out as *mut [MaybeUninit<u8>] as *mut [u8]) })
    }
}

impl Sink for Fill<'_> {
    fn pos(&self) -> usize {
        self.pos
    }
    fn bytes(&mut self, b: &[u8]) {
        if let Some(o) = self.next(b.len()) {
            o.write_copy_of_slice(b);
        }
    }
    fn zeros(&mut self, n: usize) {
        if let Some(o) = self.next(n) {
            o.fill(MaybeUninit::new(0));
        }
    }
    fn u32s(&mut self, v: &[u32]) {
        if let Some(o) = self.next(4 * v.len()) {
            for (o, x) in o.chunks_exact_mut(4).zip(v) {
                o.write_copy_of_slice(&x.to_le_bytes());
            }
        }
    }
    fn f64s(&mut self, v: &[f64]) {
        if let Some(o) = self.next(8 * v.len()) {
            for (o, x) in o.chunks_exact_mut(8).zip(v) {
                o.write_copy_of_slice(&x.to_le_bytes());
            }
        }
    }
}

/// Writes CDR into a [`Sink`].
pub(crate) struct Writer<S: Sink> {
    buf: S,
}

impl<S: Sink> Writer<S> {
    pub(crate) fn new(mut buf: S) -> Self {
        buf.bytes(&HEADER);
        Self { buf }
    }

    fn align(&mut self, to: usize) {
        let pos = self.buf.pos() - HEADER.len();
        let pad = (to - pos % to) % to;
        self.buf.zeros(pad);
    }

    pub(crate) fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.bytes(&v.to_le_bytes());
    }

    pub(crate) fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.bytes(&v.to_le_bytes());
    }

    pub(crate) fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.bytes(&v.to_le_bytes());
    }

    pub(crate) fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.bytes(s.as_bytes());
        self.buf.bytes(&[0]);
    }

    pub(crate) fn seq_u8(&mut self, v: &[u8]) {
        self.u32(v.len() as u32);
        self.buf.bytes(v);
    }

    pub(crate) fn seq_u32(&mut self, v: &[u32]) {
        self.u32(v.len() as u32);
        self.buf.u32s(v);
    }

    pub(crate) fn seq_f64(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        if v.is_empty() {
            return; // no element, no alignment (as serde writes it)
        }
        self.align(8);
        self.buf.f64s(v);
    }

    /// The fields every group message starts with, in wire order.
    fn group_header(
        &mut self,
        schema_version: u32,
        group: &str,
        step: u64,
        t_plus: f64,
        first_fiber: u32,
        group_fibers: u32,
    ) {
        self.u32(schema_version);
        self.string(group);
        self.u64(step);
        self.f64(t_plus);
        self.u32(first_fiber);
        self.u32(group_fibers);
    }

    pub(crate) fn finish(self) -> S {
        self.buf
    }
}

/// Reads CDR, every length checked against the payload before anything is allocated.
pub(crate) struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Result<Self, String> {
        if bytes.len() < 4 || bytes[0] != 0 || bytes[1] != 1 {
            return Err("missing CDR little-endian encapsulation header".into());
        }
        Ok(Self {
            data: &bytes[4..],
            pos: 0,
        })
    }

    fn align(&mut self, to: usize) {
        self.pos = self.pos.div_ceil(to) * to;
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).ok_or("length overflow")?;
        if end > self.data.len() {
            return Err(format!(
                "needs {end} bytes, payload has {}",
                self.data.len()
            ));
        }
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        self.align(N);
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    pub(crate) fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    pub(crate) fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    pub(crate) fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }

    pub(crate) fn string(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        let bytes = self.take(n)?;
        // the last byte is the terminating NUL; like the serde path, it is dropped unread
        let text = bytes.split_last().map_or(&[][..], |(_, t)| t);
        String::from_utf8(text.to_vec()).map_err(|e| e.to_string())
    }

    /// The bytes of a sequence of `n` elements of `size` bytes (aligned to `size` when
    /// not empty), checked to fit before anything is allocated.
    fn seq_bytes(&mut self, size: usize) -> Result<&'a [u8], String> {
        let n = self.u32()? as usize;
        if n == 0 {
            return Ok(&[]);
        }
        self.align(size);
        let len = n.checked_mul(size).ok_or("length overflow")?;
        self.take(len)
    }

    /// The fields every group message starts with.
    fn group_header(&mut self) -> Result<GroupHeader, String> {
        Ok(GroupHeader {
            schema_version: self.u32()?,
            group: self.string()?,
            step: self.u64()?,
            t_plus: self.f64()?,
            first_fiber: self.u32()?,
            group_fibers: self.u32()?,
        })
    }

    pub(crate) fn seq_f64(&mut self) -> Result<Vec<f64>, String> {
        let mut v = Vec::new();
        self.seq_f64_into(&mut v)?;
        Ok(v)
    }

    /// A byte sequence into `out`, its allocation reused.
    fn seq_u8_into(&mut self, out: &mut Vec<u8>) -> Result<(), String> {
        let b = self.seq_bytes(1)?;
        out.clear();
        out.extend_from_slice(b);
        Ok(())
    }

    /// A u32 sequence into `out`, its allocation reused.
    fn seq_u32_into(&mut self, out: &mut Vec<u32>) -> Result<(), String> {
        let b = self.seq_bytes(4)?;
        out.clear();
        out.extend(b.chunks_exact(4).map(|c| {
            let mut a = [0u8; 4];
            a.copy_from_slice(c);
            u32::from_le_bytes(a)
        }));
        Ok(())
    }

    /// An f64 sequence into `out`, its allocation reused.
    fn seq_f64_into(&mut self, out: &mut Vec<f64>) -> Result<(), String> {
        let b = self.seq_bytes(8)?;
        out.clear();
        out.extend(b.chunks_exact(8).map(f64_le));
        Ok(())
    }
}

/// A message written field by field into any [`Sink`].
pub(crate) trait Bulk {
    fn write_to<S: Sink>(&self, sink: S) -> S;

    /// The length of its bytes (a pass over its headers and array lengths only).
    fn bulk_len(&self) -> usize {
        self.write_to(Count::default()).pos()
    }

    /// Its bytes, in a buffer of exactly that length.
    fn to_vec(&self) -> Vec<u8> {
        self.write_to(Vec::with_capacity(self.bulk_len()))
    }

    /// Writes its bytes into `out`; false if `out` is not exactly [`Bulk::bulk_len`] long.
    fn write_exact(&self, out: &mut [u8]) -> bool {
        self.write_to(Fill::new(out)).exact()
    }

    /// Writes its bytes into memory not initialised yet; `out`, initialised, if it is
    /// exactly [`Bulk::bulk_len`] long.
    fn write_uninit<'a>(&self, out: &'a mut [MaybeUninit<u8>]) -> Option<&'a mut [u8]> {
        self.write_to(Fill::uninit(out)).finish()
    }
}

impl Bulk for FlowSamples {
    fn write_to<S: Sink>(&self, sink: S) -> S {
        let m = self;
        let mut w = Writer::new(sink);
        w.group_header(
            m.schema_version,
            &m.group,
            m.step,
            m.t_plus,
            m.first_fiber,
            m.group_fibers,
        );
        w.seq_f64(&m.velocity);
        w.seq_f64(&m.velocity_gradient);
        w.finish()
    }
}

pub(crate) fn read_samples(bytes: &[u8]) -> Result<FlowSamples, String> {
    let mut r = Reader::new(bytes)?;
    let h = r.group_header()?;
    Ok(FlowSamples {
        schema_version: h.schema_version,
        group: h.group,
        step: h.step,
        t_plus: h.t_plus,
        first_fiber: h.first_fiber,
        group_fibers: h.group_fibers,
        velocity: r.seq_f64()?,
        velocity_gradient: r.seq_f64()?,
    })
}

impl Bulk for FiberGroupMetrics {
    fn write_to<S: Sink>(&self, sink: S) -> S {
        let m = self;
        let mut w = Writer::new(sink);
        w.group_header(
            m.schema_version,
            &m.group,
            m.step,
            m.t_plus,
            m.first_fiber,
            m.group_fibers,
        );
        w.seq_f64(&m.centre_of_mass);
        w.seq_f64(&m.z1);
        w.seq_f64(&m.sigma2);
        w.seq_f64(&m.end_to_end);
        w.f64(m.mean_abs_z1);
        w.f64(m.mean_sigma2);
        w.finish()
    }
}

pub(crate) fn read_metrics(bytes: &[u8]) -> Result<FiberGroupMetrics, String> {
    let mut r = Reader::new(bytes)?;
    let h = r.group_header()?;
    Ok(FiberGroupMetrics {
        schema_version: h.schema_version,
        group: h.group,
        step: h.step,
        t_plus: h.t_plus,
        first_fiber: h.first_fiber,
        group_fibers: h.group_fibers,
        centre_of_mass: r.seq_f64()?,
        z1: r.seq_f64()?,
        sigma2: r.seq_f64()?,
        end_to_end: r.seq_f64()?,
        mean_abs_z1: r.f64()?,
        mean_sigma2: r.f64()?,
    })
}

/// FlowSamples read where they lie (e.g. in a transport's shared memory): the header
/// decoded, the two arrays left as their wire bytes, so that a receiver converts them
/// straight into its own layout with no arrays in between. [`SamplesView::read`] and
/// [`SamplesView::check`] accept exactly what `decode::<FlowSamples>` and its
/// [`crate::sanity::Sane`] check accept (test `samples_view_accepts_what_decode_accepts`).
pub struct SamplesView<'a> {
    pub header: GroupHeader,
    velocity: &'a [u8],
    velocity_gradient: &'a [u8],
}

impl<'a> SamplesView<'a> {
    /// Reads the header and finds the arrays, lengths checked; the schema version too.
    pub fn read(bytes: &'a [u8]) -> Result<Self, crate::DecodeError> {
        let malformed = |reason: String| crate::DecodeError::Malformed {
            len: bytes.len(),
            reason,
        };
        let mut r = Reader::new(bytes).map_err(malformed)?;
        let header = r.group_header().map_err(malformed)?;
        let velocity = r.seq_bytes(8).map_err(malformed)?;
        let velocity_gradient = r.seq_bytes(8).map_err(malformed)?;
        if !crate::readable_schema(header.schema_version) {
            return Err(crate::DecodeError::Version {
                got: header.schema_version,
                expected: crate::SCHEMA_VERSION,
            });
        }
        Ok(Self {
            header,
            velocity,
            velocity_gradient,
        })
    }

    /// Points sampled (velocity triples).
    pub fn len(&self) -> usize {
        self.velocity.len() / 24
    }

    pub fn is_empty(&self) -> bool {
        self.velocity.is_empty()
    }

    /// The velocity (3 per point) and gradient (9 per point, ∂v_a/∂x_b at 3a + b)
    /// arrays as the message holds them: little-endian `f64`s, where the bytes arrived.
    pub fn arrays(&self) -> (&'a [u8], &'a [u8]) {
        (self.velocity, self.velocity_gradient)
    }

    /// True if every value of both arrays is finite (read in place; with
    /// [`Self::check_shape`], the same verdict as [`Self::check`]).
    pub fn values_finite(&self) -> bool {
        crate::sanity::all_finite(floats(self.velocity))
            && crate::sanity::all_finite(floats(self.velocity_gradient))
    }

    /// The checks of `FlowSamples` (lengths, piece, time, every value finite).
    pub fn check(&self) -> Result<(), String> {
        let h = &self.header;
        crate::sanity::check_samples(
            (h.t_plus, &h.group, h.first_fiber, h.group_fibers),
            self.velocity.len() / 8,
            self.velocity_gradient.len() / 8,
            || floats(self.velocity),
            || floats(self.velocity_gradient),
        )
    }

    /// [`Self::check`] without the values' finiteness ([`Self::values_finite`]).
    pub fn check_shape(&self) -> Result<(), String> {
        let h = &self.header;
        crate::sanity::check_samples_shape(
            (h.t_plus, &h.group, h.first_fiber, h.group_fibers),
            self.velocity.len() / 8,
            self.velocity_gradient.len() / 8,
        )
    }

    /// Each point's velocity and gradient (`grad[3a + b] = ∂v_a/∂x_b`), in order.
    pub fn points(&self) -> impl Iterator<Item = ([f64; 3], [f64; 9])> + '_ {
        self.velocity
            .chunks_exact(24)
            .zip(self.velocity_gradient.chunks_exact(72))
            .map(|(v, g)| {
                let mut vel = [0.0; 3];
                let mut grad = [0.0; 9];
                for (x, b) in vel.iter_mut().zip(v.chunks_exact(8)) {
                    *x = f64_le(b);
                }
                for (x, b) in grad.iter_mut().zip(g.chunks_exact(8)) {
                    *x = f64_le(b);
                }
                (vel, grad)
            })
    }
}

#[inline(always)]
fn f64_le(b: &[u8]) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(b);
    f64::from_le_bytes(a)
}

/// The little-endian f64 values of `bytes`.
fn floats(bytes: &[u8]) -> impl Iterator<Item = f64> + Clone + '_ {
    bytes.chunks_exact(8).map(f64_le)
}

impl Bulk for FiberGroupState {
    fn write_to<S: Sink>(&self, sink: S) -> S {
        let m = self;
        let mut w = Writer::new(sink);
        w.group_header(
            m.schema_version,
            &m.group,
            m.step,
            m.t_plus,
            m.first_fiber,
            m.group_fibers,
        );
        w.seq_u32(&m.segments_per_fiber);
        w.seq_f64(&m.segment_length);
        w.seq_f64(&m.diameter);
        w.seq_f64(&m.density_ratio);
        w.seq_u8(&m.layer);
        w.seq_f64(&m.centre);
        w.seq_f64(&m.axis);
        w.seq_f64(&m.velocity);
        w.seq_f64(&m.angular_velocity);
        w.seq_f64(&m.hydro_force);
        // schema 3 had no contact arrays: a state read from it is written back as it was
        if m.schema_version >= 4 {
            w.seq_u32(&m.contact_segment);
            w.seq_f64(&m.contact_force);
            w.seq_u32(&m.contacts);
        }
        w.finish()
    }
}

pub(crate) fn read_state(bytes: &[u8]) -> Result<FiberGroupState, String> {
    let mut s = FiberGroupState::default();
    read_state_into(&mut s, bytes)?;
    Ok(s)
}

/// [`read_state`] into `out`, its arrays' allocations reused (`out` unspecified on an
/// error).
pub(crate) fn read_state_into(out: &mut FiberGroupState, bytes: &[u8]) -> Result<(), String> {
    let mut r = Reader::new(bytes)?;
    let h = r.group_header()?;
    out.schema_version = h.schema_version;
    out.group = h.group;
    out.step = h.step;
    out.t_plus = h.t_plus;
    out.first_fiber = h.first_fiber;
    out.group_fibers = h.group_fibers;
    r.seq_u32_into(&mut out.segments_per_fiber)?;
    r.seq_f64_into(&mut out.segment_length)?;
    r.seq_f64_into(&mut out.diameter)?;
    r.seq_f64_into(&mut out.density_ratio)?;
    r.seq_u8_into(&mut out.layer)?;
    r.seq_f64_into(&mut out.centre)?;
    r.seq_f64_into(&mut out.axis)?;
    r.seq_f64_into(&mut out.velocity)?;
    r.seq_f64_into(&mut out.angular_velocity)?;
    r.seq_f64_into(&mut out.hydro_force)?;
    if h.schema_version >= 4 {
        r.seq_u32_into(&mut out.contact_segment)?;
        r.seq_f64_into(&mut out.contact_force)?;
        r.seq_u32_into(&mut out.contacts)?;
    } else {
        out.contact_segment.clear();
        out.contact_force.clear();
        out.contacts.clear();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{serde_decode, serde_encode};
    use crate::fuzz::{random_payload, Rng};
    use crate::kind::Kind;

    const BULK: [Kind; 3] = [
        Kind::FlowSamples,
        Kind::FiberGroupState,
        Kind::FiberGroupMetrics,
    ];

    /// What `encode_into` writes into a slice of `encoded_len` bytes, and whether a slice
    /// one byte short or long is refused.
    fn into_slice<M: crate::Message>(m: &M) -> (Vec<u8>, bool, bool) {
        let n = crate::encoded_len(m);
        let mut exact = vec![0xAAu8; n];
        let fits = crate::encode_into(m, &mut exact);
        assert!(fits, "a slice of encoded_len bytes must fit");
        let short = n > 0 && !crate::encode_into(m, &mut vec![0u8; n - 1]);
        let long = !crate::encode_into(m, &mut vec![0u8; n + 1]);
        // into memory not initialised: the same bytes, and the same refusals
        let uninit = |len: usize| {
            let mut buf = vec![MaybeUninit::<u8>::uninit(); len];
            crate::encode_into_uninit(m, &mut buf).map(|b| b.to_vec())
        };
        assert_eq!(
            uninit(n).as_ref(),
            Some(&exact),
            "into uninitialised memory"
        );
        let short = short && (n == 0 || uninit(n - 1).is_none());
        let long = long && uninit(n + 1).is_none();
        (exact, short, long)
    }

    /// Random messages (random lengths, empty arrays, odd group-name lengths so every
    /// padding case occurs) are written to the very bytes the serde path writes — into a
    /// growing buffer and into a slice sized by `encoded_len`, initialised or not (which
    /// refuses a slice of any other length) — and read back to the same message.
    #[test]
    fn bulk_bytes_equal_the_serde_bytes() {
        let mut r = Rng::new(11);
        let groups = ["case1".to_string(), "g".into(), "stiff12".into()];
        for i in 0..20_000 {
            let ty = BULK[i % 3];
            let b = random_payload(ty, &mut r, &groups);
            // compared as bytes: NaN is among the values
            if ty == BULK[2] {
                let m: FiberGroupMetrics = serde_decode(&b).unwrap();
                assert_eq!(m.to_vec(), b);
                assert_eq!(into_slice(&m), (b.clone(), true, true));
                assert_eq!(serde_encode(&read_metrics(&b).unwrap()), b);
            } else if ty == BULK[0] {
                let m: FlowSamples = serde_decode(&b).unwrap();
                assert_eq!(m.to_vec(), b);
                assert_eq!(into_slice(&m), (b.clone(), true, true));
                assert_eq!(serde_encode(&read_samples(&b).unwrap()), b);
            } else {
                let m: FiberGroupState = serde_decode(&b).unwrap();
                assert_eq!(m.to_vec(), b);
                assert_eq!(into_slice(&m), (b.clone(), true, true));
                assert_eq!(serde_encode(&read_state(&b).unwrap()), b);
            }
        }
    }

    /// Random and corrupted FlowSamples: the in-place view with its check accepts exactly
    /// what decoding with the message's check accepts, with the same header and values;
    /// its one-pass reader (`fill_points`) reads the same values and finds them finite,
    /// with `check_shape` passing, exactly when `check` passes.
    #[test]
    fn samples_view_accepts_what_decode_accepts() {
        use crate::sanity::Sane;
        let mut r = Rng::new(13);
        let groups = ["case1".to_string(), "g".into()];
        let (mut ok, mut refused) = (0, 0);
        for i in 0..20_000 {
            let mut b = random_payload(BULK[0], &mut r, &groups);
            match i % 4 {
                0 => {}
                1 => b.truncate(r.below(b.len() as u64 + 1) as usize),
                2 => {
                    let at = r.below(b.len() as u64) as usize;
                    b[at] = r.next_u64() as u8;
                }
                _ => {
                    // a value made non-finite
                    let at = b.len().saturating_sub(8 * (1 + r.below(4) as usize));
                    if at >= 8 {
                        b[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
                    }
                }
            }
            // the in-place reader: the arrays hold the values of `points` (the gradient
            // row by row), and they are finite with a sound shape exactly when the full
            // check passes
            if let Ok(v) = SamplesView::read(&b) {
                let (vel, grad) = v.arrays();
                let want: Vec<_> = v.points().collect();
                let bits = |bytes: &[u8], per: usize| -> Vec<u64> {
                    bytes
                        .chunks_exact(8)
                        .take(per * want.len())
                        .map(|x| f64::from_le_bytes(x.try_into().expect("8 bytes")).to_bits())
                        .collect()
                };
                let want_vel: Vec<u64> = want.iter().flat_map(|p| p.0.map(f64::to_bits)).collect();
                let want_grad: Vec<u64> = want.iter().flat_map(|p| p.1.map(f64::to_bits)).collect();
                assert_eq!(bits(vel, 3), want_vel);
                assert_eq!(bits(grad, 9), want_grad);
                assert_eq!(
                    v.check_shape().is_ok() && v.values_finite(),
                    v.check().is_ok()
                );
            }
            let decoded = crate::decode::<FlowSamples>(&b)
                .map_err(|e| e.to_string())
                .and_then(|m| m.check().map(|()| m));
            let viewed = SamplesView::read(&b)
                .map_err(|e| e.to_string())
                .and_then(|v| v.check().map(|()| v));
            match (decoded, viewed) {
                (Ok(m), Ok(v)) => {
                    ok += 1;
                    assert_eq!(
                        (&v.header.group, v.header.step, v.header.first_fiber),
                        (&m.group, m.step, m.first_fiber)
                    );
                    assert_eq!(v.len(), m.velocity.len() / 3);
                    let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    let (vel, grad): (Vec<_>, Vec<_>) = v.points().unzip();
                    assert_eq!(bits(vel.as_flattened()), bits(&m.velocity));
                    assert_eq!(bits(grad.as_flattened()), bits(&m.velocity_gradient));
                }
                (Err(_), Err(_)) => refused += 1,
                (d, v) => panic!("decode {:?} but view {:?}", d.err(), v.err()),
            }
        }
        assert!(ok > 1000 && refused > 1000, "{ok} {refused}");
    }

    /// A state decoded into one used before (its arrays holding another state's values)
    /// gives what `decode` gives: the same state, bit for bit, or the same error — for
    /// 20,000 random, truncated and corrupted payloads.
    #[test]
    fn a_schema_3_state_reads_without_contact_and_writes_back_unchanged() {
        // a complete two-way state of 50 case-1 fibres, recorded by a build of schema 3
        let old: &[u8] = include_bytes!("../testdata/state-schema3.cdr");
        let s: FiberGroupState = crate::decode(old).expect("schema 3 reads");
        assert_eq!(s.schema_version, 3);
        assert_eq!((s.segments_per_fiber.len(), s.centre.len()), (50, 1050));
        assert_eq!(s.hydro_force.len(), 1050);
        assert!(
            s.contact_segment.is_empty() && s.contact_force.is_empty() && s.contacts.is_empty()
        );
        assert_eq!(crate::sanity::Sane::check(&s), Ok(()));
        // written back, the same bytes; as schema 4, the three empty arrays follow
        assert_eq!(crate::encode(&s), old);
        let mut now = s.clone();
        now.schema_version = crate::SCHEMA_VERSION;
        let bytes = crate::encode(&now);
        assert_eq!(bytes.len(), old.len() + 12);
        assert_eq!(crate::decode::<FiberGroupState>(&bytes), Ok(now));
        // a state from before schema 3 is refused by its version
        let mut older = old.to_vec();
        older[4..8].copy_from_slice(&2u32.to_le_bytes());
        let refused = crate::decode::<FiberGroupState>(&older).unwrap_err();
        assert!(matches!(
            refused,
            crate::DecodeError::Version { got: 2, .. }
        ));
        assert_eq!(
            refused.to_string(),
            "schema version 2, this build understands 3 to 5"
        );
    }

    #[test]
    fn state_decoded_into_a_used_one_is_decode() {
        let mut r = Rng::new(17);
        let groups = ["case1".to_string(), "g".into()];
        let mut used: FiberGroupState =
            crate::decode(&random_payload(BULK[1], &mut r, &groups)).unwrap();
        let (mut ok, mut refused) = (0, 0);
        for i in 0..20_000 {
            let mut b = random_payload(BULK[1], &mut r, &groups);
            match i % 3 {
                0 => {}
                1 => b.truncate(r.below(b.len() as u64 + 1) as usize),
                _ => {
                    let at = r.below(b.len() as u64) as usize;
                    b[at] = r.next_u64() as u8;
                }
            }
            let fresh = crate::decode::<FiberGroupState>(&b);
            let into = crate::decode_state_into(&mut used, &b);
            match (fresh, into) {
                (Ok(m), Ok(())) => {
                    ok += 1;
                    // compared as bytes: NaN is among the values
                    assert_eq!(crate::encode(&used), crate::encode(&m));
                }
                (Err(a), Err(b)) => {
                    refused += 1;
                    assert_eq!(a.to_string(), b.to_string());
                }
                (a, b) => panic!("decode {a:?} but decode_state_into {b:?}"),
            }
        }
        assert!(ok > 1000 && refused > 1000, "{ok} {refused}");
    }

    /// Corrupted payloads (truncated, bytes flipped, lengths inflated): the bulk reader
    /// accepts exactly what the serde path accepts, with the same message, and never panics.
    #[test]
    fn bulk_reader_accepts_what_serde_accepts() {
        /// Both paths on `b`: Some(true) both accept the same message, Some(false) both
        /// refuse, None they disagree.
        fn agree<M: crate::Message>(
            b: &[u8],
            bulk: fn(&[u8]) -> Result<M, String>,
        ) -> Option<bool> {
            match (serde_decode::<M>(b), bulk(b)) {
                // compared as bytes: NaN is among the values
                (Ok(a), Ok(c)) => (serde_encode(&a) == serde_encode(&c)).then_some(true),
                (Err(_), Err(_)) => Some(false),
                _ => None,
            }
        }
        let mut r = Rng::new(12);
        let groups = ["case1".to_string()];
        let (mut same_ok, mut same_err) = (0, 0);
        for i in 0..40_000 {
            let ty = BULK[i % 3];
            let mut b = random_payload(ty, &mut r, &groups);
            match r.below(3) {
                0 => b.truncate(r.below(b.len() as u64 + 1) as usize),
                1 => {
                    for _ in 0..1 + r.below(4) {
                        let at = r.below(b.len() as u64) as usize;
                        b[at] = r.next_u64() as u8;
                    }
                }
                _ => {
                    let at = 4 + 4 * r.below(b.len() as u64 / 4) as usize;
                    if at + 4 <= b.len() {
                        b[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
                    }
                }
            }
            let verdict = if ty == BULK[2] {
                agree(&b, read_metrics)
            } else if ty == BULK[0] {
                agree(&b, read_samples)
            } else {
                agree(&b, read_state)
            };
            match verdict {
                Some(true) => same_ok += 1,
                Some(false) => same_err += 1,
                None => panic!("serde and bulk disagree on a {ty} of {} bytes", b.len()),
            }
        }
        assert!(same_ok > 1000 && same_err > 1000, "{same_ok} {same_err}");
    }
}
