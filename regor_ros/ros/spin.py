"""The node's spin loop and executor.

**The loop** is rclpy.spin, except that a wait set spoilt by an entity destroyed while it was being
built is built again. The node destroys entities from callbacks while the executor builds its next
wait set: an ``auto`` input resubscribes when its publishers' QoS changes, a lifecycle cleanup
destroys everything. rclpy (Jazzy's 7.1.6 and Kilted's 9.1 alike) collects the entities, then adds
them to the wait set; a subscription's event handler destroyed in between raises ``InvalidHandle``
out of ``spin_once`` (ros2/rclpy#1284), which ends ``rclpy.spin`` and the node with it (a CI run on
Jazzy, when a test's driver changed its QoS). The entity is gone from the node by then, so the next
wait set, built without it, is the right one.

**The executor** runs callbacks on a pool of threads, as rclpy's MultiThreadedExecutor does: a
~/relocalize or ~/load_map call waits for a registration or a map while scans keep arriving. It
differs in one thing. rclpy yields a callback's task again on every pass until a pool thread
starts it, and MultiThreadedExecutor submits it to the pool each time and keeps every submission
in a list it scans on every pass. Under a fast input stream the pool threads wait for Python's
lock, the list grows and the loop scans it holding the lock: under a fast stream of large scans
the loop took most of the node's Python time and most inputs were lost. Here a task is submitted
once; while it waits for a thread, the loop waits for it too, without the lock.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor, wait

from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ShutdownException, TimeoutException

PENDING_WAIT_S = 0.01  # how long the loop waits for a submitted callback to start before it looks again


class PoolExecutor(Executor):
    """Callbacks on ``threads`` pool threads, each ready task submitted once (module docstring)."""

    def __init__(self, threads: int, *, context=None):
        super().__init__(context=context)
        self._pool = ThreadPoolExecutor(threads)
        self._submitted: dict = {}   # task -> the pool's future of its latest run

    def spin_once(self, timeout_sec: float | None = None) -> None:
        try:
            task, _, _ = self.wait_for_ready_callbacks(timeout_sec=timeout_sec)
        except (ShutdownException, TimeoutException):
            return
        pending = self._submitted.get(task)
        if pending is None or pending.done():
            # a coroutine callback that awaits is yielded again after each run: run it again
            self._submitted[task] = self._pool.submit(task)
        else:
            wait([pending], timeout=PENDING_WAIT_S)
        for ran in [t for t, run in self._submitted.items() if run.done()]:
            del self._submitted[ran]
            if ran.done():
                ran.result()   # the task holds its callback's exception: raised, it ends the spin, as rclpy's

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        done = super().shutdown(timeout_sec)
        self._pool.shutdown(wait=True)
        return done


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
