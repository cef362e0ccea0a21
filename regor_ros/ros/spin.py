"""The node's spin loop: rclpy.spin, except that a wait set spoilt by an entity destroyed while it
was being built is built again.

The node destroys entities from callbacks while the multi-threaded executor builds its next wait
set in another thread: an ``auto`` input resubscribes when its publishers' QoS changes, a
lifecycle cleanup destroys everything. rclpy (Jazzy's 7.1.6 and Kilted's 9.1 alike) collects the
entities, then adds them to the wait set; a subscription's event handler destroyed in between
raises ``InvalidHandle`` out of ``spin_once`` (ros2/rclpy#1284), which ends ``rclpy.spin`` and the
node with it (a CI run on Jazzy, when a test's driver changed its QoS). The entity is gone from
the node by then, so the next wait set, built without it, is the right one.
"""
from __future__ import annotations

from rclpy.exceptions import InvalidHandle


def spin(node, executor) -> None:
    """Execute the node's callbacks until the executor's context is shut down."""
    executor.add_node(node)
    try:
        while executor.context.ok():
            try:
                executor.spin_once()
            except InvalidHandle:
                continue  # an entity destroyed while the wait set was built: build it again
    finally:
        executor.remove_node(node)
