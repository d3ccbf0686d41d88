//! The `.msg` definitions (kept next to the types in `messages/msg/`), embedded.

pub const RUN_ANNOUNCEMENT: &str = include_str!("../msg/RunAnnouncement.msg");
pub const FLOW_STATUS: &str = include_str!("../msg/FlowStatus.msg");
pub const FLOW_PROFILES: &str = include_str!("../msg/FlowProfiles.msg");
pub const FLOW_SLICE: &str = include_str!("../msg/FlowSlice.msg");
pub const FLOW_SAMPLES: &str = include_str!("../msg/FlowSamples.msg");
pub const FIBER_GROUP_STATE: &str = include_str!("../msg/FiberGroupState.msg");
pub const FIBER_GROUP_METRICS: &str = include_str!("../msg/FiberGroupMetrics.msg");
pub const FIBER_FREE_STEP: &str = include_str!("../msg/FiberFreeStep.msg");
pub const FIBER_CONTACT_SOLVED: &str = include_str!("../msg/FiberContactSolved.msg");
pub const HEARTBEAT: &str = include_str!("../msg/Heartbeat.msg");
/// `sensor_msgs/msg/PointCloud2` with its dependencies, in MCAP ros2msg form.
pub const POINT_CLOUD2: &str = include_str!("../msg/PointCloud2.msg");
pub const POINT_CLOUD2_NAME: &str = "sensor_msgs/msg/PointCloud2";
/// `sensor_msgs/msg/Image` with its dependencies, in MCAP ros2msg form.
pub const IMAGE: &str = include_str!("../msg/Image.msg");
pub const IMAGE_NAME: &str = "sensor_msgs/msg/Image";

/// Schema text by ROS 2 type name ("" if unknown).
pub fn text(type_name: &str) -> &'static str {
    match type_name {
        POINT_CLOUD2_NAME => POINT_CLOUD2,
        IMAGE_NAME => IMAGE,
        _ => crate::Kind::of_type_name(type_name).map_or("", kind_text),
    }
}

/// The schema text of a kind of message.
pub const fn kind_text(kind: crate::Kind) -> &'static str {
    use crate::Kind;
    match kind {
        Kind::RunAnnouncement => RUN_ANNOUNCEMENT,
        Kind::FlowStatus => FLOW_STATUS,
        Kind::FlowSamples => FLOW_SAMPLES,
        Kind::FlowProfiles => FLOW_PROFILES,
        Kind::FlowSlice => FLOW_SLICE,
        Kind::FiberGroupState => FIBER_GROUP_STATE,
        Kind::FiberGroupMetrics => FIBER_GROUP_METRICS,
        Kind::FiberFreeStep => FIBER_FREE_STEP,
        Kind::FiberContactSolved => FIBER_CONTACT_SOLVED,
        Kind::Heartbeat => HEARTBEAT,
    }
}

/// Checks that a payload of the given type decodes (used by the recorder to drop garbage).
pub fn validate(type_name: &str, bytes: &[u8]) -> Result<(), crate::DecodeError> {
    use crate::types::*;
    use crate::{decode, Kind};
    let Some(kind) = Kind::of_type_name(type_name) else {
        return Err(crate::DecodeError::Malformed {
            len: bytes.len(),
            reason: format!("unknown type {type_name}"),
        });
    };
    match kind {
        Kind::RunAnnouncement => decode::<RunAnnouncement>(bytes).map(|_| ()),
        Kind::FlowStatus => decode::<FlowStatus>(bytes).map(|_| ()),
        Kind::FlowSamples => decode::<FlowSamples>(bytes).map(|_| ()),
        Kind::FlowProfiles => decode::<FlowProfiles>(bytes).map(|_| ()),
        Kind::FlowSlice => decode::<FlowSlice>(bytes).map(|_| ()),
        Kind::FiberGroupState => decode::<FiberGroupState>(bytes).map(|_| ()),
        Kind::FiberGroupMetrics => decode::<FiberGroupMetrics>(bytes).map(|_| ()),
        Kind::FiberFreeStep => decode::<FiberFreeStep>(bytes).map(|_| ()),
        Kind::FiberContactSolved => decode::<FiberContactSolved>(bytes).map(|_| ()),
        Kind::Heartbeat => decode::<Heartbeat>(bytes).map(|_| ()),
    }
}

/// Walks a payload against a flat `.msg` definition (primitives, strings and sequences of
/// them) and checks every length fits the buffer, before any allocation happens. This guards
/// the CDR decoder against hostile lengths (a string claiming 4 GiB) and checks the `.msg`
/// text and the serde layout agree.
pub fn check_layout(schema: &str, bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 4 || bytes[0] != 0 || bytes[1] != 1 {
        return Err("missing CDR little-endian encapsulation header".into());
    }
    let data = &bytes[4..];
    let mut pos = 0usize;
    let align = |pos: &mut usize, a: usize| *pos = (*pos).div_ceil(a) * a;
    let take = |pos: &mut usize, n: usize| -> Result<(), String> {
        let end = pos.checked_add(n).ok_or("length overflow")?;
        if end > data.len() {
            return Err(format!("needs {end} bytes, payload has {}", data.len()));
        }
        *pos = end;
        Ok(())
    };
    let read_u32 = |pos: &mut usize| -> Result<usize, String> {
        align(pos, 4);
        let p = *pos;
        take(pos, 4)?;
        let mut b = [0u8; 4];
        b.copy_from_slice(&data[p..p + 4]);
        Ok(u32::from_le_bytes(b) as usize)
    };
    for line in schema.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let Some((ty, _name)) = line.split_once(' ') else {
            return Err(format!("bad schema line {line:?}"));
        };
        let (base, seq) = match ty.strip_suffix("[]") {
            Some(b) => (b, true),
            None => (ty, false),
        };
        let size = match base {
            "uint8" | "int8" | "bool" => 1,
            "uint32" | "int32" | "float32" => 4,
            "uint64" | "int64" | "float64" => 8,
            "string" => 0,
            other => return Err(format!("unsupported field type {other}")),
        };
        let count = if seq { read_u32(&mut pos)? } else { 1 };
        if size > 0 {
            // fixed-size elements: aligned once, then contiguous
            if count > 0 {
                align(&mut pos, size);
                take(&mut pos, count.checked_mul(size).ok_or("length overflow")?)?;
            }
            continue;
        }
        // strings: each its own length
        for _ in 0..count {
            let n = read_u32(&mut pos)?;
            take(&mut pos, n)?;
            if count > data.len() {
                return Err(format!(
                    "sequence of {count} cannot fit {} bytes",
                    data.len()
                ));
            }
        }
    }
    Ok(())
}
