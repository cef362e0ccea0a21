"""Helpers for tests of the installed register_node: colcon build, process, parameter calls."""
import signal
import subprocess
import time
from pathlib import Path

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

TIMEOUT = 90.0


class NodeProcess:
    """The installed executable, started through the install space's setup script. Every one
    started is remembered: the suite fails if one outlives its test (conftest.py)."""

    started: list["NodeProcess"] = []

    def __init__(self, install: Path, *ros_args: str, env=None):
        exe = install / "regor_ros" / "lib" / "regor_ros" / "register_node"
        assert exe.exists(), "colcon did not install lib/regor_ros/register_node"
        command = f"source {install}/setup.bash && exec {exe} --ros-args {' '.join(ros_args)}"
        self.log = open(install.parent / f"node-{time.monotonic_ns()}.log", "w+")
        self.proc = subprocess.Popen(["bash", "-c", command], stdout=self.log,
                                     stderr=subprocess.STDOUT, env=env)
        NodeProcess.started.append(self)

    def output(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text()

    def stop(self) -> float:
        """SIGINT; returns how long the process took to exit."""
        start = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        return time.monotonic() - start


def kill_survivors(nodes) -> list:
    """The nodes still running, each killed: what a suite must not leave behind."""
    alive = [node for node in nodes if node.proc.poll() is None]
    for node in alive:
        node.proc.kill()
        node.proc.wait(timeout=10)
    return alive


def call(client, srv_type, name, request, resend_every=None):
    """The service's response, waiting up to TIMEOUT. ``resend_every`` (seconds; for a request
    that can be repeated, a query): send it again while unanswered. A service can be discovered
    before its reply path is matched, and on a loaded machine the first reply is then lost."""
    cli = client.create_client(srv_type, f"/register_node/{name}")
    assert cli.wait_for_service(timeout_sec=TIMEOUT)
    deadline = time.monotonic() + TIMEOUT
    future = cli.call_async(request)
    while not client.spin_until(future.done, min(resend_every or TIMEOUT, max(deadline - time.monotonic(), 0))):
        if resend_every is None or time.monotonic() >= deadline:
            break
        future = cli.call_async(request)
    client.destroy_client(cli)
    return future.result()


def set_param(client, name, value):
    if isinstance(value, list):
        pv = ParameterValue(type=ParameterType.PARAMETER_INTEGER_ARRAY, integer_array_value=value)
    elif isinstance(value, bool):
        pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
    elif isinstance(value, int):
        pv = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
    elif isinstance(value, float):
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
    else:
        pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    request = SetParameters.Request(parameters=[Parameter(name=name, value=pv)])
    return call(client, SetParameters, "set_parameters", request).results[0]
