//! Test helpers shared by the transports' tests.

use crate::Outgoing;

/// Writes `n` bytes counting up from `first`, or refuses to write when `n` is 0.
pub(crate) struct Counting {
    pub first: u8,
    pub n: usize,
}

impl Counting {
    /// The bytes it writes.
    pub fn bytes(&self) -> Vec<u8> {
        (0..self.n)
            .map(|i| self.first.wrapping_add(i as u8))
            .collect()
    }
}

impl Outgoing for Counting {
    fn len(&self) -> usize {
        self.n.max(1)
    }
    fn write(&self, out: &mut [u8]) -> bool {
        for (i, b) in out.iter_mut().enumerate() {
            *b = self.first.wrapping_add(i as u8);
        }
        self.n > 0
    }
}
