//! Opening ROS 2 topics: the QoS profiles the settings name, and a
//! subscription or publication on a topic named in full.

use ros2_client::qos::{History, WhenFull};
use ros2_client::{MessageTypeName, Name, Node, Publisher, QosProfile, Subscription};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::BridgeError;
use crate::settings::Reliability;

/// A ROS 2 error, with what was being done.
pub fn ros<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> BridgeError + '_ {
    move |e| BridgeError::Ros(format!("{what}: {e:?}"))
}

/// Volatile, keeping the last `depth`; reliable ones fail a publication
/// when the send window is full rather than wait.
pub fn qos(reliability: Reliability, depth: usize) -> QosProfile {
    let base = QosProfile::publisher_default().history(History::KeepLast { depth });
    match reliability {
        Reliability::BestEffort => base.reliability_best_effort(),
        Reliability::Reliable => base.reliability_reliable(WhenFull::Fail),
    }
}

fn name(full: &str) -> Result<Name, BridgeError> {
    Name::parse(full).map_err(|e| BridgeError::Ros(format!("topic {full}: {e:?}")))
}

/// Subscribes to topic `full` of type `kind`.
pub fn subscribe<M: DeserializeOwned + 'static>(
    node: &mut Node,
    full: &str,
    kind: MessageTypeName,
    qos: &QosProfile,
) -> Result<Subscription<M>, BridgeError> {
    let t = node.create_topic(&name(full)?, kind, qos).map_err(ros(full))?;
    node.create_subscription(&t, None).map_err(ros(full))
}

/// Publishes on topic `full` of type `kind`.
pub fn advertise<M: Serialize>(
    node: &mut Node,
    full: &str,
    kind: MessageTypeName,
    qos: &QosProfile,
) -> Result<Publisher<M>, BridgeError> {
    let t = node.create_topic(&name(full)?, kind, qos).map_err(ros(full))?;
    node.create_publisher(&t, None).map_err(ros(full))
}
