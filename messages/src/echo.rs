//! A message as text, field by field, the way `ros2 topic echo` prints one: `name: value`
//! lines (nested fields indented), long arrays shortened to their length and first values,
//! `---` after each message.

use crate::codec::{decode, DecodeError, Message};
use crate::kind::Kind;
use crate::types::*;
use serde_json::Value;

/// The decoded fields of a message on `topic` (its type from the topic's path), arrays
/// longer than `max_items` shortened; an error if the topic carries no known type or the
/// bytes do not decode as it.
pub fn echo_text(topic: &str, bytes: &[u8], max_items: usize) -> Result<String, DecodeError> {
    let malformed = |reason: String| DecodeError::Malformed {
        len: bytes.len(),
        reason,
    };
    let kind = crate::topics::kind_of(topic)
        .ok_or_else(|| malformed(format!("no message type for topic {topic}")))?;
    let value = match kind {
        Kind::RunAnnouncement => fields::<RunAnnouncement>(bytes)?,
        Kind::Heartbeat => fields::<Heartbeat>(bytes)?,
        Kind::FlowStatus => fields::<FlowStatus>(bytes)?,
        Kind::FlowProfiles => fields::<FlowProfiles>(bytes)?,
        Kind::FlowSlice => fields::<FlowSlice>(bytes)?,
        Kind::FlowSamples => fields::<FlowSamples>(bytes)?,
        Kind::FiberGroupState => fields::<FiberGroupState>(bytes)?,
        Kind::FiberGroupMetrics => fields::<FiberGroupMetrics>(bytes)?,
        Kind::FiberFreeStep => fields::<FiberFreeStep>(bytes)?,
        Kind::FiberContactSolved => fields::<FiberContactSolved>(bytes)?,
    };
    let mut out = String::new();
    render(&value, 0, max_items, &mut out);
    out.push_str("---\n");
    Ok(out)
}

fn fields<M: Message>(bytes: &[u8]) -> Result<Value, DecodeError> {
    let m: M = decode(bytes)?;
    serde_json::to_value(&m).map_err(|e| DecodeError::Malformed {
        len: bytes.len(),
        reason: e.to_string(),
    })
}

/// `name: value` lines of an object at `indent` spaces.
fn render(v: &Value, indent: usize, max_items: usize, out: &mut String) {
    let Value::Object(map) = v else {
        out.push_str(&format!("{}{}\n", " ".repeat(indent), scalar(v)));
        return;
    };
    for (k, v) in map {
        let pad = " ".repeat(indent);
        match v {
            Value::Object(_) => {
                out.push_str(&format!("{pad}{k}:\n"));
                render(v, indent + 2, max_items, out);
            }
            Value::Array(a) if a.len() > max_items => {
                let first: Vec<String> = a.iter().take(max_items).map(scalar).collect();
                out.push_str(&format!(
                    "{pad}{k}: [{}, ...] ({} values)\n",
                    first.join(", "),
                    a.len()
                ));
            }
            Value::Array(a) => {
                let all: Vec<String> = a.iter().map(scalar).collect();
                out.push_str(&format!("{pad}{k}: [{}]\n", all.join(", ")));
            }
            _ => out.push_str(&format!("{pad}{k}: {}\n", scalar(v))),
        }
    }
}

fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        // NaN and infinities serialise as null
        Value::Null => "nan".into(),
        Value::Array(a) => format!("[{} values]", a.len()),
        Value::Object(_) => "{...}".into(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::encode;

    /// A status prints every field on its own line; a long array of a state is shortened
    /// to its first values and its length; garbage and unknown topics are errors.
    #[test]
    fn fields_print_one_per_line_and_long_arrays_shorten() {
        let status = FlowStatus {
            schema_version: crate::SCHEMA_VERSION,
            step: 40,
            t_plus: 10.0,
            dt_plus: 0.25,
            cfl: 0.9,
            max_divergence: 1e-12,
            bulk_velocity: 15.47,
            re_tau: f64::NAN,
            pressure_gradient: 1.0,
            fiber_force_plus: vec![],
        };
        let text = echo_text("fiberflow/r/flow/status", &encode(&status), 5).unwrap();
        assert!(
            text.contains("step: 40\n") && text.contains("t_plus: 10.0\n"),
            "{text}"
        );
        assert!(
            text.contains("re_tau: nan\n") && text.ends_with("---\n"),
            "{text}"
        );
        let state = FiberGroupState {
            schema_version: crate::SCHEMA_VERSION,
            group: "case1".into(),
            centre: (0..21).map(f64::from).collect(),
            ..Default::default()
        };
        let text = echo_text("fiberflow/r/fibers/case1/state", &encode(&state), 3).unwrap();
        assert!(text.contains("group: case1\n"), "{text}");
        assert!(
            text.contains("centre: [0.0, 1.0, 2.0, ...] (21 values)\n"),
            "{text}"
        );
        assert!(echo_text("fiberflow/r/flow/status", &[1, 2, 3], 5).is_err());
        assert!(echo_text("elsewhere/x", &encode(&status), 5).is_err());
    }
}
