//! The ROS 2 `std_msgs/Header` the derived channels carry (CDR layout via serde).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    /// A header stamped with simulated time (1 s per t+, as the MCAP log times) in frame
    /// `frame_id`.
    pub fn at_t_plus(t_plus: f64, frame_id: &str) -> Self {
        let secs = t_plus.max(0.0);
        Self {
            stamp: Time {
                sec: secs.floor() as i32,
                nanosec: ((secs - secs.floor()) * 1e9) as u32,
            },
            frame_id: frame_id.into(),
        }
    }
}
