"""The node's spin loop survives an entity destroyed while the executor builds its wait set, as
an ``auto`` input's resubscription or a lifecycle cleanup can do from a callback in the other
executor thread (ros2/rclpy#1284: it ended the node in a CI run on Jazzy)."""
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rclpy.waitable import NumberOfEntities, Waitable
from std_msgs.msg import String

from regor_ros.ros.spin import spin


class DestroysWhileCounted(Waitable):
    """A waitable (no entities of its own) that destroys a subscription when the executor counts
    the wait set's entities: after the subscription's event handlers were collected and entered,
    before they are added. The interleaving of the race, made certain."""

    def __init__(self, node, subscription):
        super().__init__(node.default_callback_group)
        self.node, self.subscription = node, subscription

    def get_num_entities(self):
        if self.subscription is not None:
            self.node.destroy_subscription(self.subscription)
            self.subscription = None
        return NumberOfEntities()

    def add_to_wait_set(self, wait_set):
        pass

    def __enter__(self):  # nothing of its own to keep alive
        return self

    def __exit__(self, *exc_info):
        return None

    def is_ready(self, wait_set):
        return False

    def take_data(self):
        return None

    async def execute(self, taken_data):
        pass


def test_spin_survives_a_subscription_destroyed_while_the_wait_set_is_built():
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("regor_spin_test", context=context)
    subscription = node.create_subscription(String, "regor_spin_test", lambda msg: None, QoSProfile(depth=1))
    assert subscription.event_handlers, "the subscription has no event handlers: nothing to race"
    node.add_waitable(DestroysWhileCounted(node, subscription))
    turns = []
    node.create_timer(0.01, lambda: turns.append(1) if len(turns) < 5 else rclpy.shutdown(context=context))
    executor = SingleThreadedExecutor(context=context)
    try:
        spin(node, executor)  # returns when the timer shuts the context down
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert len(turns) == 5 and subscription not in node.subscriptions
