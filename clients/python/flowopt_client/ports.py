"""The iceoryx2 ports a controller uses, opened with the daemon's settings.

Per team there are four services under a prefix (``flowopt`` by default):
``<prefix>/<team>/state`` (``StateSnapshot``, controller to daemon) and
``<prefix>/<team>/plan`` (``JointTrajectory``, daemon to controllers) with
latest-value semantics, and the event services ``<prefix>/<team>/state/ready``
and ``<prefix>/<team>/plan/ready``, notified after every send so a reader
sleeps in a listener instead of polling. The settings below are those of
``client-lib/src/ports.rs``: an opener may ask for no more than the creator.
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable

import iceoryx2 as iox2

from .messages import WIRE_VERSION, JointTrajectory, StateSnapshot, check_team_name, write_team
from .plan import Followed, Follower, MessageError, Plan, Sent

#: Publishers the state service admits: one state source per team (a
#: second live controller cannot publish).
STATE_PUBLISHERS = 1
#: Publishers the plan service admits (a restarted daemon joins before its
#: dead predecessor is cleaned up).
PLAN_PUBLISHERS = 2
#: Subscribers a service admits.
MAX_SUBSCRIBERS = 16
#: Nodes that may open a service.
MAX_NODES = 32
#: Notifiers an event service admits.
MAX_NOTIFIERS = 8
#: Listeners an event service admits.
MAX_LISTENERS = MAX_SUBSCRIBERS


def monotonic_ns() -> int:
    """``CLOCK_MONOTONIC`` in nanoseconds: the clock of every wire timestamp."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


class TeamChannel:
    """The names of one team's four services under ``prefix``."""

    def __init__(self, prefix: str, team: str):
        """Raises ``ValueError`` for a team name that does not fit a message."""
        check_team_name(team)
        self.prefix = prefix
        self.team = team
        self.state = f"{prefix}/{team}/state"
        self.state_ready = f"{prefix}/{team}/state/ready"
        self.plan = f"{prefix}/{team}/plan"
        self.plan_ready = f"{prefix}/{team}/plan/ready"


class Endpoint:
    """One iceoryx2 node (of the default domain) that opens the ports.

    iceoryx2's signal handling is disabled, as in the Rust client: Ctrl-C
    reaches Python as ``KeyboardInterrupt``.
    """

    def __init__(self, name: str = "flowopt-python-controller"):
        """A node named ``name``."""
        self.node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(name))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )

    def topic(self, name: str, payload: type) -> iox2.PortFactoryPublishSubscribe:
        """Opens (or creates) the publish-subscribe service ``name`` of
        ``payload`` (``StateSnapshot`` or ``JointTrajectory``) with the
        daemon's settings: for tools that need raw ports."""
        publishers = STATE_PUBLISHERS if payload is StateSnapshot else PLAN_PUBLISHERS
        try:
            return (
                self.node.service_builder(iox2.ServiceName.new(name))
                .publish_subscribe(payload)
                .subscriber_max_buffer_size(1)
                .history_size(1)
                .enable_safe_overflow(True)
                .subscriber_max_borrowed_samples(2)
                .max_publishers(publishers)
                .max_subscribers(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
            )
        except iox2.PublishSubscribeOpenOrCreateError as error:
            raise RuntimeError(
                f"cannot open or create the service {name} ({payload.type_name()}): {error!r}"
            ) from error

    def event(self, name: str) -> iox2.PortFactoryEvent:
        """Opens (or creates) the event service ``name`` with the daemon's settings."""
        try:
            return (
                self.node.service_builder(iox2.ServiceName.new(name))
                .event()
                .max_notifiers(MAX_NOTIFIERS)
                .max_listeners(MAX_LISTENERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
            )
        except iox2.EventOpenOrCreateError as error:
            raise RuntimeError(f"cannot open or create the event service {name}: {error!r}") from error

    def state_publisher(self, channel: TeamChannel) -> StatePublisher:
        """Publishes snapshots of ``channel``'s team, as its one state source.

        Raises ``RuntimeError`` naming the team while another live controller
        publishes its state; a crashed one's resources are removed first, so
        its successor takes over at once.
        """
        topic = self.topic(channel.state, StateSnapshot)
        try:
            publisher = topic.publisher_builder().create()
        except iox2.PublisherCreateError:
            self.node.try_cleanup_dead_nodes()
            try:
                publisher = topic.publisher_builder().create()
            except iox2.PublisherCreateError as error:
                raise RuntimeError(
                    f"team {channel.team!r} already has a live controller publishing on {channel.state}; "
                    "a team has one state source (stop the other controller first)"
                ) from error
        notifier = self.event(channel.state_ready).notifier_builder().create()
        return StatePublisher(publisher, notifier, channel.team)

    def plan_subscriber(self, channel: TeamChannel, states: StatePublisher) -> PlanSubscriber:
        """Receives the newest plan of ``channel``'s team and keeps the
        trajectory to follow, from answers to the snapshots ``states``
        publishes only (never another process's)."""
        subscriber = self.topic(channel.plan, JointTrajectory).subscriber_builder().buffer_size(1).create()
        listener = self.event(channel.plan_ready).listener_builder().create()
        return PlanSubscriber(subscriber, listener, Follower(states.sent))

    def plan_watcher(self, channel: TeamChannel) -> PlanSubscriber:
        """Receives the newest plan of ``channel``'s team, for a process that
        only watches (a viewer, a logger): it never has a trajectory to follow."""
        subscriber = self.topic(channel.plan, JointTrajectory).subscriber_builder().buffer_size(1).create()
        listener = self.event(channel.plan_ready).listener_builder().create()
        return PlanSubscriber(subscriber, listener, Follower())


class StatePublisher:
    """A controller's port for snapshots (made by ``Endpoint.state_publisher``)."""

    def __init__(self, publisher: iox2.Publisher, notifier: iox2.Notifier, team: str):
        """Wraps the ports; the first snapshot gets sequence 1."""
        self._publisher = publisher
        self._notifier = notifier
        self.team = team
        self.next_sequence = 1
        self.sent = Sent()

    def publish_with(self, fill: Callable[[StateSnapshot], None]) -> int:
        """Publishes a snapshot written in place by ``fill`` and wakes the daemon.

        ``fill`` receives the shared-memory snapshot zeroed apart from
        ``version``, ``team``, ``sequence`` (one more than the last) and
        ``timestamp_ns`` (now): it sets ``dim``, ``robots``, the robot states
        (``messages.robot_array`` gives a numpy view) and the obstacles, and
        may set ``timestamp_ns`` to the measurement time. Returns the sequence.
        """
        sequence = self.next_sequence
        uninit = self._publisher.loan_uninit()
        snapshot = uninit.payload().contents
        ctypes.memset(ctypes.addressof(snapshot), 0, ctypes.sizeof(StateSnapshot))
        snapshot.version = WIRE_VERSION
        write_team(snapshot, self.team)
        snapshot.sequence = sequence
        snapshot.timestamp_ns = monotonic_ns()
        fill(snapshot)
        stamped = (snapshot.sequence, snapshot.timestamp_ns)
        uninit.assume_init().send()
        self.sent.record(*stamped)
        self._notifier.notify()
        self.next_sequence += 1
        return sequence


class PlanSubscriber:
    """A controller's port for plans: the newest message, copied out of
    shared memory, and the trajectory to follow by the followability
    contract (made by ``Endpoint.plan_subscriber``)."""

    def __init__(self, subscriber: iox2.Subscriber, listener: iox2.Listener, follower: Follower):
        """Wraps the ports."""
        self._subscriber = subscriber
        self._listener = listener
        self.follower = follower

    def latest(self) -> Plan | None:
        """The newest plan not yet taken (older ones are dropped), or ``None``.

        It also becomes the trajectory to follow (``to_follow``). A message
        answering another snapshot than this controller's own is returned
        but changes nothing; one that cannot be read (a status,
        reason or shape no daemon writes) leaves nothing to follow and is
        returned as ``None``.
        """
        newest = None
        while (sample := self._subscriber.receive()) is not None:
            if newest is not None:
                newest.delete()
            newest = sample
        if newest is None:
            return None
        try:
            return self.follower.take(newest.payload().contents)
        except MessageError:
            return None
        finally:
            newest.delete()

    def wait(self, timeout_s: float) -> Plan | None:
        """The newest plan not yet taken, waiting up to ``timeout_s`` seconds
        for the daemon's wake-up; ``None`` if none came."""
        deadline = time.monotonic() + timeout_s
        while True:
            self._listener.try_wait()
            plan = self.latest()
            if plan is not None:
                return plan
            left = deadline - time.monotonic()
            if left <= 0.0:
                return None
            self._listener.timed_wait(iox2.Duration.from_secs_f64(left))

    def to_follow(self) -> Followed | None:
        """The trajectory to follow now, or ``None``: bring the robots to rest."""
        return self.follower.current
