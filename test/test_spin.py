"""The node's spin loop survives an entity destroyed while the executor builds its wait set, as
an ``auto`` input's resubscription or a lifecycle cleanup can do from a callback in the other
executor thread (ros2/rclpy#1284: it ended the node in a CI run on Jazzy); its executor does not
spin on a task waiting for a pool thread."""
import threading
import time

import pytest
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rclpy.waitable import NumberOfEntities, Waitable
from std_msgs.msg import String

from regor_ros.ros.spin import PENDING_WAIT_S, PoolExecutor, spin


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


class CountingPasses(PoolExecutor):
    """The node's executor, counting the ready tasks its loop is handed."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.passes = 0

    def wait_for_ready_callbacks(self, *args, **kwargs):
        self.passes += 1
        return super().wait_for_ready_callbacks(*args, **kwargs)


def wake_until(executor, event):
    """Wake the executor every millisecond, as callbacks ending and inputs arriving do under load."""
    while not event.wait(0.001):
        executor.wake()


def test_a_task_waiting_for_a_pool_thread_is_waited_for_not_spun_on():
    """rclpy yields a ready task again on every pass until a pool thread starts it. With the only
    thread held by a long callback and the executor woken every millisecond, MultiThreadedExecutor
    submits the waiting task again on each wake (some 500 passes in the half second); the node's
    executor submits it once and waits for it between passes."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("regor_pool_test", context=context)
    release, started, ran = threading.Event(), threading.Event(), []

    def hold_the_thread():
        if not started.is_set():
            started.set()
            release.wait(10.0)

    node.create_timer(0.001, hold_the_thread, callback_group=MutuallyExclusiveCallbackGroup())
    node.create_timer(0.001, lambda: ran.append(1), callback_group=MutuallyExclusiveCallbackGroup())
    executor = CountingPasses(1, context=context)
    executor.add_node(node)
    try:
        while not started.is_set():
            executor.spin_once(timeout_sec=1.0)
        before, start = executor.passes, time.monotonic()
        threading.Timer(0.5, release.set).start()
        threading.Thread(target=wake_until, args=(executor, release), daemon=True).start()
        while not release.is_set():
            executor.spin_once(timeout_sec=1.0)
        held, passes = time.monotonic() - start, executor.passes - before
        while len(ran) < 3:   # the waiting callback runs once the thread is free
            executor.spin_once(timeout_sec=1.0)
    finally:
        release.set()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    # each pass waits up to PENDING_WAIT_S for the waiting task: a slow machine makes fewer passes
    assert passes <= held / PENDING_WAIT_S + 10, (passes, held)


def test_a_callback_exception_ends_the_spin_as_rclpys_executors_do():
    """rclpy's task keeps its callback's exception; the executor raises it from spin_once, so a
    broken callback stops the node loudly instead of failing silently on every call."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("regor_pool_raise_test", context=context)

    def broken():
        raise RuntimeError("broken callback")

    node.create_timer(0.001, broken)
    executor = PoolExecutor(1, context=context)
    executor.add_node(node)
    try:
        with pytest.raises(RuntimeError, match="broken callback"):
            for _ in range(1000):
                executor.spin_once(timeout_sec=1.0)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
