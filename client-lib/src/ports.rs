//! The iceoryx2 ports that carry the messages, with the service settings
//! in one place so the daemon and every client open identical services.
//!
//! Per team there are four services under a prefix (`flowopt` by default):
//! `<prefix>/<team>/state` and `<prefix>/<team>/plan` carry the messages
//! with latest-value semantics (subscriber buffer 1, safe overflow, history
//! 1: a reader always gets the newest one and a late joiner the last one),
//! and `<prefix>/<team>/state/ready` and `<prefix>/<team>/plan/ready` are
//! event services a publisher notifies after each send, so a reader can
//! sleep in a listener or a WaitSet instead of polling.

use std::cell::Cell;
use std::fmt::Debug;
use std::time::{Duration, Instant};

use iceoryx2::node::{NodeCreationFailure, NodeListFailure};
use iceoryx2::port::listener::{Listener, ListenerCreateError, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::port::{LoanError, ReceiveError, SendError};
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as Topic;
use thiserror::Error;

use crate::clock::monotonic_ns;
use crate::follow::{Followed, Follower, Sent};
use crate::messages::{
    JointTrajectory, MAX_COEFFS, MAX_ROBOTS, MessageError, RobotState, StateSnapshot, WIRE_VERSION, check_team_name,
};

/// Publishers a plan service admits (two, so a restarted daemon can join
/// before its dead predecessor is cleaned up; the team lock keeps a second
/// live one out).
const PLAN_PUBLISHERS: usize = 2;
/// Publishers a state service admits: one state source per team. A second
/// live controller cannot publish; a crashed one's successor takes its
/// place once the dead node is cleaned up (by the successor, or by the
/// daemon within [`DEAD_NODE_SWEEP`]).
const STATE_PUBLISHERS: usize = 1;
/// Notifiers an event service admits.
const MAX_NOTIFIERS: usize = 8;
/// How often the daemon removes the resources of dead nodes, so that a
/// crashed controller's successor can publish.
pub const DEAD_NODE_SWEEP: Duration = Duration::from_millis(250);
/// Subscribers a service admits.
const MAX_SUBSCRIBERS: usize = 16;
/// Nodes that may open a service.
const MAX_NODES: usize = 32;

/// Why a port could not be opened or used. iceoryx2's own error is kept as
/// the [`std::error::Error::source`], so a caller can tell, say, an
/// incompatible service from a failed loan.
#[derive(Debug, Error)]
pub enum PortError {
    /// A prefix, team or node name that does not make a valid iceoryx2 name.
    #[error("PortError::ServiceName: invalid service or node name {0:?}")]
    ServiceName(String),
    /// A team name that does not fit a message.
    #[error("PortError::Team: {0}")]
    Team(#[from] MessageError),
    /// The iceoryx2 node could not be created.
    #[error("PortError::Node: cannot create the iceoryx2 node")]
    Node(#[source] NodeCreationFailure),
    /// A publish-subscribe service could not be opened (for example one
    /// created with another payload type or smaller limits).
    #[error("PortError::Topic: cannot open or create the service {service}")]
    Topic {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    /// An event service could not be opened.
    #[error("PortError::Event: cannot open or create the event service {service}")]
    Event {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: EventOpenOrCreateError,
    },
    /// A publisher could not be created.
    #[error("PortError::Publisher: cannot create a publisher")]
    Publisher(#[source] PublisherCreateError),
    /// Another live controller publishes the team's state: a team has one
    /// state source.
    #[error(
        "PortError::StateTaken: team {team:?} already has a live controller publishing on {service}; \
         a team has one state source (stop the other controller first)"
    )]
    StateTaken {
        /// The team.
        team: String,
        /// Its state service.
        service: String,
    },
    /// A subscriber could not be created.
    #[error("PortError::Subscriber: cannot create a subscriber")]
    Subscriber(#[source] SubscriberCreateError),
    /// A notifier could not be created.
    #[error("PortError::Notifier: cannot create a notifier")]
    Notifier(#[source] NotifierCreateError),
    /// A listener could not be created.
    #[error("PortError::Listener: cannot create a listener")]
    Listener(#[source] ListenerCreateError),
    /// No sample could be loaned for a message.
    #[error("PortError::Loan: cannot loan a sample")]
    Loan(#[source] LoanError),
    /// A message could not be sent.
    #[error("PortError::Send: cannot send")]
    Send(#[source] SendError),
    /// A message could not be received.
    #[error("PortError::Receive: cannot receive")]
    Receive(#[source] ReceiveError),
    /// The wake-up event could not be sent.
    #[error("PortError::Notify: cannot notify the listeners")]
    Notify(#[source] NotifierNotifyError),
    /// Waiting for a wake-up event failed.
    #[error("PortError::Wait: cannot wait for an event")]
    Wait(#[source] ListenerWaitError),
    /// The nodes of the domain could not be listed.
    #[error("PortError::ListNodes: cannot list the iceoryx2 nodes")]
    ListNodes(#[source] NodeListFailure),
}

impl PortError {
    /// Whether this is a service's publishers all taken.
    fn publishers_exhausted(&self) -> bool {
        matches!(self, PortError::Publisher(PublisherCreateError::ExceedsMaxSupportedPublishers))
    }
}

/// The names of one team's four services.
#[derive(Debug, Clone)]
pub struct TeamChannel {
    team: String,
    state: ServiceName,
    state_ready: ServiceName,
    plan: ServiceName,
    plan_ready: ServiceName,
}

impl TeamChannel {
    /// The services of `team` under `prefix` (`flowopt` in production; a
    /// unique prefix isolates tests and demos).
    pub fn new(prefix: &str, team: &str) -> Result<Self, PortError> {
        let name = |suffix: &str| {
            let s = format!("{prefix}/{team}/{suffix}");
            ServiceName::new(&s).map_err(|_| PortError::ServiceName(s))
        };
        check_team_name(team)?;
        Ok(Self {
            team: team.to_string(),
            state: name("state")?,
            state_ready: name("state/ready")?,
            plan: name("plan")?,
            plan_ready: name("plan/ready")?,
        })
    }

    /// The team's name.
    pub fn team(&self) -> &str {
        &self.team
    }
}

/// A message type that may be sent: plain data (every field an integer, a
/// float or an array of them, so every byte pattern is a valid value) laid
/// out as a header and then `MAX_ROBOTS` per-robot entries, of which a
/// message uses a prefix.
///
/// # Safety
/// Implementors guarantee that every byte pattern is a valid value and that
/// `HEADER + MAX_ROBOTS * ENTRY` is the type's size.
unsafe trait Wire: Debug + ZeroCopySend + 'static {
    /// Publishers a service of this message admits.
    const PUBLISHERS: usize;
    /// Bytes before the per-robot entries.
    const HEADER: usize;
    /// Bytes of one per-robot entry.
    const ENTRY: usize;
    /// The entries a written message declares in use.
    fn entries(&self) -> usize;
}

// SAFETY: integers, floats and arrays of them; the robots come last.
unsafe impl Wire for StateSnapshot {
    const PUBLISHERS: usize = STATE_PUBLISHERS;
    const HEADER: usize = std::mem::offset_of!(StateSnapshot, robot);
    const ENTRY: usize = size_of::<RobotState>();
    fn entries(&self) -> usize {
        (self.robots as usize).min(MAX_ROBOTS)
    }
}

// SAFETY: integers, floats and arrays of them (the status and reason are
// `u32`s on the wire); the coefficients come last.
unsafe impl Wire for JointTrajectory {
    const PUBLISHERS: usize = PLAN_PUBLISHERS;
    const HEADER: usize = std::mem::offset_of!(JointTrajectory, coeffs);
    const ENTRY: usize = size_of::<[[f64; MAX_COEFFS]; 3]>();
    fn entries(&self) -> usize {
        (self.robots as usize).min(MAX_ROBOTS)
    }
}

/// Loans of a publisher that clear the whole message: iceoryx2's pool of a
/// publisher of these services (`max_subscribers * (buffer + borrowed) +
/// history + loans`), so that every chunk starts cleared whatever order the
/// pool hands them out in.
const FULL_CLEARS: usize = MAX_SUBSCRIBERS * (1 + 2) + 1 + 2;

/// One iceoryx2 node: the handle a process (or thread: the ports are not
/// `Send`) opens its ports from. Signal handling is left to the
/// application (iceoryx2's own handlers are disabled).
#[derive(Debug)]
pub struct Endpoint {
    node: Node<ipc::Service>,
}

impl Endpoint {
    /// A node named `name` in the default iceoryx2 domain. Creating it
    /// also removes the resources of dead nodes.
    pub fn new(name: &str) -> Result<Self, PortError> {
        let node_name = NodeName::new(name).map_err(|_| PortError::ServiceName(name.to_string()))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(PortError::Node)?;
        Ok(Self { node })
    }

    /// The underlying node.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// For a controller: publishes snapshots of `channel`'s team, as its
    /// one state source. While another live controller publishes them this
    /// fails with [`PortError::StateTaken`]; a crashed one is cleaned up
    /// first ([`cleanup_dead_nodes`]), so its successor takes over at once.
    pub fn state_publisher(&self, channel: &TeamChannel) -> Result<StatePublisher, PortError> {
        let outlet = match self.outlet(&channel.state, &channel.state_ready) {
            Err(e) if e.publishers_exhausted() => {
                cleanup_dead_nodes()?;
                self.outlet(&channel.state, &channel.state_ready)
            }
            other => other,
        };
        let outlet = outlet.map_err(|e| {
            if e.publishers_exhausted() {
                PortError::StateTaken { team: channel.team.clone(), service: channel.state.to_string() }
            } else {
                e
            }
        })?;
        Ok(StatePublisher { outlet, team: channel.team.clone(), next_sequence: 1, sent: Sent::default() })
    }

    /// For a controller: receives the newest plan of `channel`'s team and
    /// keeps the trajectory to follow, from answers to the snapshots
    /// `states` publishes ([`Follower::answering`]): never another
    /// process's, nor one kept for late joiners.
    pub fn plan_subscriber(&self, channel: &TeamChannel, states: &StatePublisher) -> Result<PlanSubscriber, PortError> {
        let inlet = self.inlet(&channel.plan, &channel.plan_ready)?;
        Ok(PlanSubscriber { inlet, follower: Follower::answering(states.sent.clone()) })
    }

    /// For a process that only watches `channel`'s plans (a viewer, a
    /// logger): the newest plan of the team; it never has a trajectory to
    /// follow ([`PlanSubscriber::to_follow`] is `None`).
    pub fn plan_watcher(&self, channel: &TeamChannel) -> Result<PlanSubscriber, PortError> {
        let inlet = self.inlet(&channel.plan, &channel.plan_ready)?;
        Ok(PlanSubscriber { inlet, follower: Follower::watcher() })
    }

    /// For the daemon: receives the newest snapshot of `channel`'s team.
    pub fn state_subscriber(&self, channel: &TeamChannel) -> Result<StateSubscriber, PortError> {
        Ok(StateSubscriber {
            inlet: self.inlet(&channel.state, &channel.state_ready)?,
            service: self.topic::<StateSnapshot>(&channel.state)?,
        })
    }

    /// For the daemon: publishes plans for `channel`'s team.
    pub fn plan_publisher(&self, channel: &TeamChannel) -> Result<PlanPublisher, PortError> {
        Ok(PlanPublisher { outlet: self.outlet(&channel.plan, &channel.plan_ready)?, team: channel.team.clone() })
    }

    fn topic<T: Wire>(&self, name: &ServiceName) -> Result<Topic<ipc::Service, T, ()>, PortError> {
        self.node
            .service_builder(name)
            .publish_subscribe::<T>()
            .subscriber_max_buffer_size(1)
            .history_size(1)
            .enable_safe_overflow(true)
            .subscriber_max_borrowed_samples(2)
            .max_publishers(T::PUBLISHERS)
            .max_subscribers(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|source| PortError::Topic { service: name.to_string(), source })
    }

    fn event(
        &self,
        name: &ServiceName,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, PortError> {
        self.node
            .service_builder(name)
            .event()
            .max_notifiers(MAX_NOTIFIERS)
            .max_listeners(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|source| PortError::Event { service: name.to_string(), source })
    }

    fn outlet<T: Wire>(&self, topic: &ServiceName, ready: &ServiceName) -> Result<Outlet<T>, PortError> {
        Ok(Outlet::new(
            self.topic::<T>(topic)?.publisher_builder().create().map_err(PortError::Publisher)?,
            self.event(ready)?.notifier_builder().create().map_err(PortError::Notifier)?,
        ))
    }

    fn inlet<T: Wire>(&self, topic: &ServiceName, ready: &ServiceName) -> Result<Inlet<T>, PortError> {
        Ok(Inlet {
            subscriber: self
                .topic::<T>(topic)?
                .subscriber_builder()
                .buffer_size(1)
                .create()
                .map_err(PortError::Subscriber)?,
            listener: self.event(ready)?.listener_builder().create().map_err(PortError::Listener)?,
        })
    }
}

/// A received message, read in place from shared memory.
pub type Received<T> = Sample<ipc::Service, T, ()>;

/// Publisher + notifier of one message type.
#[derive(Debug)]
struct Outlet<T: Wire> {
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    /// Loans so far.
    loans: Cell<usize>,
    /// The most entries any message of this publisher declared in use.
    high_water: Cell<usize>,
}

impl<T: Wire> Outlet<T> {
    fn new(publisher: Publisher<ipc::Service, T, ()>, notifier: Notifier<ipc::Service>) -> Self {
        Self { publisher, notifier, loans: Cell::new(0), high_water: Cell::new(0) }
    }

    /// Loans a sample, zeroes it, lets `fill` write it in place, sends it
    /// and wakes the listeners; returns the subscribers reached.
    ///
    /// Zeroing the whole capacity (98 KB for a plan) would cost more than
    /// the rest of a round trip, so after the first [`FULL_CLEARS`] loans
    /// only the header and as many entries as any earlier message of this
    /// publisher used are zeroed: the rest of a chunk has only ever held
    /// zeros.
    fn publish_with(&self, fill: impl FnOnce(&mut T)) -> Result<usize, PortError> {
        let mut sample = self.publisher.loan_uninit().map_err(PortError::Loan)?;
        let clear = if self.loans.get() < FULL_CLEARS {
            size_of::<T>()
        } else {
            (T::HEADER + self.high_water.get() * T::ENTRY).min(size_of::<T>())
        };
        // SAFETY: `Wire` types are valid for every byte pattern, and the
        // chunk's bytes are initialised (shared memory is created zeroed and
        // only ever written with values of `T`); the first `clear` bytes are
        // zeroed here.
        let mut sample = unsafe {
            sample.payload_mut().as_mut_ptr().cast::<u8>().write_bytes(0, clear);
            sample.assume_init()
        };
        fill(sample.payload_mut());
        self.loans.set(self.loans.get().saturating_add(1));
        self.high_water.set(self.high_water.get().max(sample.payload().entries()));
        let reached = sample.send().map_err(PortError::Send)?;
        self.notifier.notify().map_err(PortError::Notify)?;
        Ok(reached)
    }
}

/// Subscriber + listener of one message type.
#[derive(Debug)]
struct Inlet<T: Wire> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
}

impl<T: Wire> Inlet<T> {
    fn latest(&self) -> Result<Option<Received<T>>, PortError> {
        let mut latest = None;
        while let Some(sample) = self.subscriber.receive().map_err(PortError::Receive)? {
            latest = Some(sample);
        }
        Ok(latest)
    }

    fn wait(&self, timeout: Duration) -> Result<Option<Received<T>>, PortError> {
        let deadline = Instant::now() + timeout;
        loop {
            self.drain_events()?;
            if let Some(sample) = self.latest()? {
                return Ok(Some(sample));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.listener.timed_wait(|_| {}, left).map_err(PortError::Wait)?;
        }
    }

    fn drain_events(&self) -> Result<(), PortError> {
        self.listener.try_wait(|_| {}).map_err(PortError::Wait)?;
        Ok(())
    }
}

/// A controller's port for snapshots.
#[derive(Debug)]
pub struct StatePublisher {
    outlet: Outlet<StateSnapshot>,
    team: String,
    next_sequence: u64,
    /// The snapshots published, for the controller's plan subscriber.
    sent: Sent,
}

impl StatePublisher {
    /// Publishes a snapshot written in place by `fill`, which receives it
    /// zeroed apart from `version`, `team`, `sequence` (one more than the
    /// last; starts at 1) and `timestamp_ns` (now): set `dim`, `robots`,
    /// the robot states and the obstacles, and overwrite `timestamp_ns`
    /// with the measurement time if it is earlier. Returns the sequence.
    pub fn publish_with(&mut self, fill: impl FnOnce(&mut StateSnapshot)) -> Result<u64, PortError> {
        let sequence = self.next_sequence;
        let team = &self.team;
        let mut stamped = (sequence, 0);
        self.outlet.publish_with(|s| {
            s.version = WIRE_VERSION;
            // The channel checked the name.
            let _ = s.set_team(team);
            s.sequence = sequence;
            s.timestamp_ns = monotonic_ns();
            fill(s);
            stamped = (s.sequence, s.timestamp_ns);
        })?;
        self.sent.record(stamped.0, stamped.1);
        self.next_sequence += 1;
        Ok(sequence)
    }
}

/// A controller's port for plans: newest-plan semantics, and the
/// trajectory to follow by the followability contract ([`Follower`]).
#[derive(Debug)]
pub struct PlanSubscriber {
    inlet: Inlet<JointTrajectory>,
    follower: Follower,
}

impl PlanSubscriber {
    /// The newest plan not yet taken, if any (older ones are dropped); it
    /// also becomes the trajectory to follow ([`Self::to_follow`]).
    pub fn latest(&mut self) -> Result<Option<Received<JointTrajectory>>, PortError> {
        let latest = self.inlet.latest()?;
        self.take(latest.as_deref());
        Ok(latest)
    }

    /// The newest plan not yet taken, waiting up to `timeout` for one; it
    /// also becomes the trajectory to follow ([`Self::to_follow`]).
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Received<JointTrajectory>>, PortError> {
        let latest = self.inlet.wait(timeout)?;
        self.take(latest.as_deref());
        Ok(latest)
    }

    /// The trajectory to follow now, from the newest plan taken: `None`
    /// when there is none (no plan yet, or the daemon said there is no
    /// verified one): bring the robots to rest.
    pub fn to_follow(&self) -> Option<&Followed> {
        self.follower.current()
    }

    fn take(&mut self, msg: Option<&JointTrajectory>) {
        if let Some(msg) = msg {
            // A message that cannot be read leaves nothing to follow.
            let _ = self.follower.take(msg);
        }
    }
}

/// The daemon's port for snapshots.
#[derive(Debug)]
pub struct StateSubscriber {
    inlet: Inlet<StateSnapshot>,
    service: Topic<ipc::Service, StateSnapshot, ()>,
}

impl StateSubscriber {
    /// The newest snapshot not yet taken, if any; clears pending wake-ups.
    pub fn latest(&self) -> Result<Option<Received<StateSnapshot>>, PortError> {
        self.inlet.drain_events()?;
        self.inlet.latest()
    }

    /// The newest snapshot not yet taken, waiting up to `timeout` for one.
    pub fn wait(&self, timeout: Duration) -> Result<Option<Received<StateSnapshot>>, PortError> {
        self.inlet.wait(timeout)
    }

    /// The listener woken on every snapshot, to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.inlet.listener
    }

    /// Whether the publisher `id` (a sample's origin) is still registered
    /// on the service (a dead process's stays until it is cleaned up).
    pub fn has_publisher(&self, id: u128) -> bool {
        let mut found = false;
        self.service.dynamic_config().list_publishers(|p| {
            found = p.publisher_id.value() == id;
            if found { CallbackProgression::Stop } else { CallbackProgression::Continue }
        });
        found
    }
}

/// The daemon's port for plans.
#[derive(Debug)]
pub struct PlanPublisher {
    outlet: Outlet<JointTrajectory>,
    team: String,
}

impl PlanPublisher {
    /// Publishes a plan written in place by `fill`, which receives it zeroed
    /// apart from `version` and `team`; `published_ns` is stamped after
    /// `fill`. Returns the subscribers reached.
    pub fn publish_with(&self, fill: impl FnOnce(&mut JointTrajectory)) -> Result<usize, PortError> {
        let team = &self.team;
        self.outlet.publish_with(|p| {
            p.version = WIRE_VERSION;
            let _ = p.set_team(team);
            p.reason_index = u32::MAX;
            fill(p);
            p.published_ns = monotonic_ns();
        })
    }
}

/// Removes the resources of dead nodes in the default domain (a crashed
/// daemon or controller); returns how many were cleaned.
pub fn cleanup_dead_nodes() -> Result<usize, PortError> {
    let mut dead = Vec::new();
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    })
    .map_err(PortError::ListNodes)?;
    Ok(dead.into_iter().filter(|d| d.clone().try_remove_stale_resources().is_ok()).count())
}
