//! zenoh transport (peer mode). Secure defaults: listens on loopback only, multicast
//! scouting off; peers find each other by connecting to the run's rendezvous endpoint.

use crate::{Bus, BusError, Subscription};
use std::sync::mpsc::channel;
use zenoh::Wait;

/// Connection settings of one node.
#[derive(Debug, Clone, PartialEq)]
pub struct ZenohSettings {
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:0`.
    pub listen: Vec<String>,
    /// Endpoints to connect to (the rendezvous peer).
    pub connect: Vec<String>,
    /// Multicast scouting (off by default: nothing is announced on the LAN).
    pub multicast_scouting: bool,
}

impl Default for ZenohSettings {
    fn default() -> Self {
        Self {
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: vec![],
            multicast_scouting: false,
        }
    }
}

/// A zenoh session used as a bus.
pub struct ZenohBus {
    session: zenoh::Session,
}

fn terr<E: std::fmt::Display>(e: E) -> BusError {
    BusError::Transport(e.to_string())
}

impl ZenohBus {
    pub fn open(s: &ZenohSettings) -> Result<Self, BusError> {
        let mut c = zenoh::Config::default();
        let list = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        c.insert_json5("mode", "\"peer\"").map_err(terr)?;
        c.insert_json5("listen/endpoints", &list(&s.listen))
            .map_err(terr)?;
        c.insert_json5("connect/endpoints", &list(&s.connect))
            .map_err(terr)?;
        c.insert_json5(
            "scouting/multicast/enabled",
            if s.multicast_scouting {
                "true"
            } else {
                "false"
            },
        )
        .map_err(terr)?;
        let session = zenoh::open(c).wait().map_err(terr)?;
        Ok(Self { session })
    }
}

impl Bus for ZenohBus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        self.session
            .put(topic, payload.to_vec())
            // lockstep coupling must never lose a message: block instead of dropping
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait()
            .map_err(terr)
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        let sub = self
            .session
            .declare_subscriber(pattern)
            .callback(move |sample| {
                let topic = sample.key_expr().as_str().to_string();
                let bytes = sample.payload().to_bytes().into_owned();
                let _ = tx.send((topic, bytes));
            })
            .wait()
            .map_err(terr)?;
        Ok(Subscription::new(rx, Some(Box::new(sub))))
    }

    fn name(&self) -> &'static str {
        "zenoh"
    }
}
