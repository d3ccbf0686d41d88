//! ROS 2 CDR (little-endian, with the 4-byte encapsulation header) for every message, and
//! a checked decoder: never panics on input from the bus.

use crate::schema;
use crate::SCHEMA_VERSION;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::mem::MaybeUninit;

/// What a decode can fail with (the message is then dropped and counted).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error("undecodable payload ({len} bytes): {reason}")]
    Malformed { len: usize, reason: String },
    #[error(
        "schema version {got}, this build understands {} to {expected}",
        crate::OLDEST_READABLE_SCHEMA
    )]
    Version { got: u32, expected: u32 },
}

/// A bus message: its ROS 2 type name and schema version accessor.
pub trait Message: Serialize + DeserializeOwned {
    /// ROS 2 type name, e.g. `fiberflow_msgs/msg/FlowStatus`.
    const TYPE_NAME: &'static str;
    fn schema_version(&self) -> u32;
    /// The `.msg` definition text.
    fn schema_text() -> &'static str {
        schema::text(Self::TYPE_NAME)
    }
    /// Its CDR bytes (the serde path unless the type writes its arrays in bulk).
    fn write_cdr(&self) -> Vec<u8> {
        serde_encode(self)
    }
    /// The length of its CDR bytes.
    fn encoded_len(&self) -> usize {
        self.write_cdr().len()
    }
    /// Writes its CDR bytes into `out` (e.g. a transport's loaned shared memory); false,
    /// with `out` unspecified, if `out` is not exactly [`Message::encoded_len`] long.
    fn write_cdr_into(&self, out: &mut [u8]) -> bool {
        let b = self.write_cdr();
        let fits = b.len() == out.len();
        if fits {
            out.copy_from_slice(&b);
        }
        fits
    }
    /// Writes its CDR bytes into memory not initialised yet (a transport's loan, so that
    /// it need not be zeroed first); `out`, initialised, if it is exactly
    /// [`Message::encoded_len`] long.
    fn write_cdr_uninit<'a>(&self, out: &'a mut [MaybeUninit<u8>]) -> Option<&'a mut [u8]> {
        let b = self.write_cdr();
        (b.len() == out.len()).then(|| out.write_copy_of_slice(&b))
    }
    /// Reads CDR bytes, lengths checked before any allocation (the serde path after a
    /// layout walk unless the type reads its arrays in bulk).
    fn read_cdr(bytes: &[u8]) -> Result<Self, DecodeError> {
        serde_decode(bytes)
    }
}

macro_rules! message {
    ($t:ident) => {
        impl Message for crate::types::$t {
            const TYPE_NAME: &'static str = concat!("fiberflow_msgs/msg/", stringify!($t));
            fn schema_version(&self) -> u32 {
                self.schema_version
            }
        }
    };
    ($t:ident, bulk, $read:path) => {
        impl Message for crate::types::$t {
            const TYPE_NAME: &'static str = concat!("fiberflow_msgs/msg/", stringify!($t));
            fn schema_version(&self) -> u32 {
                self.schema_version
            }
            fn write_cdr(&self) -> Vec<u8> {
                crate::bulk::Bulk::to_vec(self)
            }
            fn encoded_len(&self) -> usize {
                crate::bulk::Bulk::bulk_len(self)
            }
            fn write_cdr_into(&self, out: &mut [u8]) -> bool {
                crate::bulk::Bulk::write_exact(self, out)
            }
            fn write_cdr_uninit<'a>(
                &self,
                out: &'a mut [std::mem::MaybeUninit<u8>],
            ) -> Option<&'a mut [u8]> {
                crate::bulk::Bulk::write_uninit(self, out)
            }
            fn read_cdr(bytes: &[u8]) -> Result<Self, DecodeError> {
                $read(bytes).map_err(|reason| DecodeError::Malformed {
                    len: bytes.len(),
                    reason,
                })
            }
        }
    };
}
message!(RunAnnouncement);
message!(FlowStatus);
message!(FlowProfiles);
message!(FlowSlice);
message!(FlowSamples, bulk, crate::bulk::read_samples);
message!(FiberGroupState, bulk, crate::bulk::read_state);
message!(FiberGroupMetrics, bulk, crate::bulk::read_metrics);
message!(Heartbeat);
message!(FiberFreeStep);
message!(FiberContactSolved);

/// Encodes as CDR little-endian with encapsulation header.
pub fn encode<M: Message>(m: &M) -> Vec<u8> {
    m.write_cdr()
}

/// The length of `m`'s CDR bytes (what [`encode_into`] needs).
pub fn encoded_len<M: Message>(m: &M) -> usize {
    m.encoded_len()
}

/// Encodes into `out`, which must be exactly [`encoded_len`] long (false, with `out`
/// unspecified, if it is not): the bulk messages write straight into it, e.g. into a
/// transport's loaned shared memory, with no buffer in between.
pub fn encode_into<M: Message>(m: &M, out: &mut [u8]) -> bool {
    m.write_cdr_into(out)
}

/// Encodes into memory not initialised yet, which must be exactly [`encoded_len`] long:
/// `out`, now initialised, or None if it is not that long (`out` then unspecified).
pub fn encode_into_uninit<'a, M: Message>(
    m: &M,
    out: &'a mut [MaybeUninit<u8>],
) -> Option<&'a mut [u8]> {
    m.write_cdr_uninit(out)
}

/// CDR through serde (the generic path; the bulk messages are tested and benched against it).
pub fn serde_encode<M: Serialize + ?Sized>(m: &M) -> Vec<u8> {
    // serialising plain structs of numbers, strings and sequences cannot fail
    cdr::serialize::<_, _, cdr::CdrLe>(m, cdr::Infinite).unwrap_or_default()
}

/// CDR through serde, after the layout walk that guards it against hostile lengths.
pub fn serde_decode<M: Message>(bytes: &[u8]) -> Result<M, DecodeError> {
    schema::check_layout(M::schema_text(), bytes).map_err(|reason| DecodeError::Malformed {
        len: bytes.len(),
        reason,
    })?;
    cdr::deserialize_from(bytes, cdr::size::Bounded(bytes.len() as u64)).map_err(|e| {
        DecodeError::Malformed {
            len: bytes.len(),
            reason: e.to_string(),
        }
    })
}

/// Decodes and checks the schema version.
pub fn decode<M: Message>(bytes: &[u8]) -> Result<M, DecodeError> {
    let m = M::read_cdr(bytes)?;
    if !crate::readable_schema(m.schema_version()) {
        return Err(DecodeError::Version {
            got: m.schema_version(),
            expected: SCHEMA_VERSION,
        });
    }
    Ok(m)
}

/// [`decode`] of a FiberGroupState into `out`, reusing its arrays' allocations (the flow
/// node decodes tens of MB of states per step at scale): the same answers as `decode`
/// (test `bulk::tests::state_decoded_into_a_used_one_is_decode`); `out` is unspecified
/// after an error.
pub fn decode_state_into(
    out: &mut crate::FiberGroupState,
    bytes: &[u8],
) -> Result<(), DecodeError> {
    crate::bulk::read_state_into(out, bytes).map_err(|reason| DecodeError::Malformed {
        len: bytes.len(),
        reason,
    })?;
    if !crate::readable_schema(out.schema_version) {
        return Err(DecodeError::Version {
            got: out.schema_version,
            expected: SCHEMA_VERSION,
        });
    }
    Ok(())
}

pub use crate::bulk::GroupHeader;

/// Reads only the leading [`GroupHeader`] of a group message (its arrays are neither
/// walked nor copied): what a receiver needs to decide whether it wants the message.
pub fn peek_group_header(bytes: &[u8]) -> Result<GroupHeader, DecodeError> {
    let h: GroupHeader = cdr::deserialize_from(bytes, cdr::size::Bounded(bytes.len() as u64))
        .map_err(|e| DecodeError::Malformed {
            len: bytes.len(),
            reason: e.to_string(),
        })?;
    if !crate::readable_schema(h.schema_version) {
        return Err(DecodeError::Version {
            got: h.schema_version,
            expected: SCHEMA_VERSION,
        });
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::*;

    fn state() -> FiberGroupState {
        FiberGroupState {
            schema_version: SCHEMA_VERSION,
            group: "case1".into(),
            step: 7,
            t_plus: 1.5,
            first_fiber: 0,
            group_fibers: 1,
            segments_per_fiber: vec![2],
            segment_length: vec![3.0],
            diameter: vec![0.232],
            density_ratio: vec![1150.0],
            layer: vec![2],
            centre: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            axis: vec![0.0, 1.0, 0.0, 0.0, 1.0, 0.0],
            velocity: vec![0.5; 6],
            angular_velocity: vec![0.0; 6],
            hydro_force: vec![],
            contact_segment: vec![],
            contact_force: vec![],
            contacts: vec![],
        }
    }

    /// Every type's `.msg` text walks its own encoding exactly (schema and serde agree).
    #[test]
    fn msg_text_matches_serde_layout() {
        let s = state();
        let b = encode(&s);
        schema::check_layout(FiberGroupState::schema_text(), &b).unwrap();
        let hb = Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Ready,
            step: 3,
            dropped: 0,
        };
        schema::check_layout(Heartbeat::schema_text(), &encode(&hb)).unwrap();
        let ann = RunAnnouncement {
            schema_version: SCHEMA_VERSION,
            run_id: "r".into(),
            config_digest: "d".into(),
            groups: vec!["a".into(), "bb".into()],
            steps: 4,
            dt_plus: 0.1,
            box_plus: vec![1.0, 2.0, 3.0],
        };
        assert_eq!(decode::<RunAnnouncement>(&encode(&ann)).unwrap(), ann);
        // a truncated payload is rejected by the walker
        assert!(schema::check_layout(FiberGroupState::schema_text(), &b[..b.len() - 3]).is_err());
    }

    #[test]
    fn round_trip() {
        let s = state();
        let b = encode(&s);
        assert_eq!(
            &b[..4],
            &[0, 1, 0, 0],
            "CDR little-endian encapsulation header"
        );
        assert_eq!(decode::<FiberGroupState>(&b).unwrap(), s);
    }

    #[test]
    fn wrong_version_and_garbage_are_errors_not_panics() {
        let mut s = state();
        s.schema_version = 99;
        assert!(matches!(
            decode::<FiberGroupState>(&encode(&s)),
            Err(DecodeError::Version { got: 99, .. })
        ));
        let mut x: u64 = 0x1234_5678;
        for len in 0..2000usize {
            let bytes: Vec<u8> = (0..len % 300)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect();
            assert!(decode::<FiberGroupState>(&bytes).is_err());
            assert!(decode::<FlowSamples>(&bytes).is_err());
        }
        // a huge claimed sequence length must not allocate or panic
        let mut b = encode(&state());
        b.truncate(40);
        b.extend_from_slice(&[0xff, 0xff, 0xff, 0x7f]);
        assert!(decode::<FiberGroupState>(&b).is_err());
    }

    /// The header of a state, samples and metrics message reads back as encoded, and a
    /// truncated or foreign payload is an error, not a panic.
    #[test]
    fn group_header_peeks_without_the_arrays() {
        let st = state();
        let h = peek_group_header(&encode(&st)).unwrap();
        assert_eq!(
            (
                h.group.as_str(),
                h.step,
                h.t_plus,
                h.first_fiber,
                h.group_fibers
            ),
            ("case1", 7, 1.5, 0, 1)
        );
        let m = FiberGroupMetrics {
            schema_version: SCHEMA_VERSION,
            group: "g2".into(),
            step: 9,
            t_plus: 2.0,
            first_fiber: 3,
            group_fibers: 10,
            centre_of_mass: vec![0.0; 3],
            z1: vec![1.0],
            sigma2: vec![0.0],
            end_to_end: vec![1.0],
            mean_abs_z1: 1.0,
            mean_sigma2: 0.0,
        };
        let h = peek_group_header(&encode(&m)).unwrap();
        assert_eq!((h.step, h.first_fiber, h.group_fibers), (9, 3, 10));
        let b = encode(&st);
        assert!(peek_group_header(&b[..10]).is_err());
        assert!(peek_group_header(&[]).is_err());
    }

    /// A lifecycle state is one byte on the wire; a byte that names no state does not
    /// decode (the receiver drops and counts the message).
    #[test]
    fn a_heartbeat_of_no_known_state_does_not_decode() {
        let hb = Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Complete,
            step: 3,
            dropped: 0,
        };
        let mut b = encode(&hb);
        // encapsulation (4), schema_version (4), the node's length (4) and "flow\0" (5)
        assert_eq!(b[17], 8);
        assert_eq!(decode::<Heartbeat>(&b).unwrap(), hb);
        b[17] = 9;
        let e = decode::<Heartbeat>(&b).unwrap_err().to_string();
        assert!(e.contains("unknown lifecycle state 9"), "{e}");
    }
}
