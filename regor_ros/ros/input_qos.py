"""Subscriptions whose QoS follows what the publishers offer (``auto``), as rosbag2 records.

A best-effort subscription turns a reliable driver's link best effort: a multi-megabyte cloud
then travels as UDP fragments, and one lost fragment loses it. A reliable subscription, on the
other hand, never matches a best-effort publisher, and a transient-local one never matches a
volatile publisher. So ``auto`` asks for the most every publisher on the topic offers: reliable
when all of them are reliable, transient local when all of them are (a latched map), best effort
and volatile otherwise. It is decided when the first publisher appears and again whenever the
publishers' offer changes; the explicit kinds stay fixed. Until then an ``auto`` input listens
best effort and volatile (what any publisher can match), so it shows in the node's graph.
"""
from __future__ import annotations

from collections.abc import Callable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

QOS_KINDS = ("auto", "sensor_data", "reliable", "transient_local")
AUTO_DEPTH = 5  # as the sensor-data profile: a burst is taken in order (each counted), the newest kept


def fixed_profile(kind: str) -> QoSProfile:
    """The profile of an explicit kind."""
    if kind == "sensor_data":
        return qos_profile_sensor_data
    durability = (DurabilityPolicy.TRANSIENT_LOCAL if kind == "transient_local"
                  else DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE, durability=durability)


def stream_profile(depth: int) -> QoSProfile:
    """A high-rate stream's (odometry, IMU): best effort, which accepts reliable and best-effort
    publishers alike, with a queue deep enough for a burst between executor turns."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)


def offered_profile(publisher_profiles) -> QoSProfile | None:
    """The profile that matches every one of the publishers' and gets the most from them; None
    when there is no publisher."""
    profiles = list(publisher_profiles)
    if not profiles:
        return None
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in profiles)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=AUTO_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def describe(profile: QoSProfile | None) -> str:
    if profile is None:
        return "waiting for a publisher"
    reliability = "reliable" if profile.reliability == ReliabilityPolicy.RELIABLE else "best effort"
    durability = ", transient local" if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL else ""
    return reliability + durability


UNDECIDED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=AUTO_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)  # what an auto input listens with before any publisher


class InputSubscription:
    """One input topic: a fixed subscription, or (``auto``) one that is recreated with the
    publishers' offer whenever ``update`` finds it changed."""

    def __init__(self, node, msg_type, topic: str, callback: Callable, kind: str):
        self._node, self._type, self._topic, self._callback = node, msg_type, topic, callback
        self.auto = kind == "auto"
        self.profile: QoSProfile | None = None   # the publishers' offer followed (auto), or the fixed one
        self._subscription = None
        self._subscribe(UNDECIDED if self.auto else fixed_profile(kind))
        if self.auto:
            self.profile = None

    def update(self) -> None:
        """Follow the publishers' offer (auto only): resubscribe when it changed."""
        if not self.auto:
            return
        name = self._node.resolve_topic_name(self._topic)
        wanted = offered_profile(info.qos_profile for info in self._node.get_publishers_info_by_topic(name))
        if wanted is None or self._same(wanted):
            return  # no publisher left: keep listening as before
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
        self._subscribe(wanted)
        self._node.get_logger().info(f"{name}: subscribed {describe(wanted)}, as its publishers offer")

    def _same(self, wanted: QoSProfile) -> bool:
        return self.profile is not None and (self.profile.reliability, self.profile.durability) == \
            (wanted.reliability, wanted.durability)

    def _subscribe(self, profile: QoSProfile) -> None:
        self.profile = profile
        self._subscription = self._node.create_subscription(self._type, self._topic, self._callback, profile)

    def destroy(self) -> None:
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
            self._subscription = None

    def state(self) -> str:
        return ("auto: " if self.auto else "") + describe(self.profile)
