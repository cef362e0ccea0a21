"""The command-line tools answer --help and argument errors before loading what registering needs
(open3d, the compiled kernels, scipy's spatial and statistics modules): each is asked in a fresh
interpreter, which then lists what it had loaded."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

# the module of every command setup.py installs but the node's (its --help: test_node.py)
TOOLS = [m for m in re.findall(r'"[\w-]+ = ([\w.]+):main"', (REPO / "setup.py").read_text())
         if not m.startswith("regor_ros.ros.")]
HEAVY = ["open3d", "numba", "scipy.spatial", "scipy.stats", "regor_ros.core.pipeline", "regor_ros.core.kernels"]

PROBE = """
import json, sys
from {tool} import main
try:
    main({argv!r})
except SystemExit as exc:
    code = exc.code
print(json.dumps({{"code": code, "loaded": [m for m in {heavy!r} if m in sys.modules]}}))
"""


def probe(tool: str, argv: list[str]) -> dict:
    run = subprocess.run([sys.executable, "-c", PROBE.format(tool=tool, argv=argv, heavy=HEAVY)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.splitlines()[-1])


@pytest.mark.parametrize("tool", TOOLS)
def test_help_answers_without_the_registration_modules(tool):
    answer = probe(tool, ["--help"])
    assert answer == {"code": 0, "loaded": []}


@pytest.mark.parametrize("tool", TOOLS)
def test_an_unknown_option_is_refused_without_the_registration_modules(tool):
    answer = probe(tool, ["--no-such-option"])
    assert answer == {"code": 2, "loaded": []}


def test_the_core_loads_a_name_when_it_is_asked_for():
    """The core's public face is lazy: the configuration alone does not load the pipeline, and
    every public name still resolves."""
    code = ("import sys, regor_ros.core as core; from regor_ros.core import RegorConfig; "
            "light = 'regor_ros.core.pipeline' not in sys.modules; "
            "missing = [n for n in core.__all__ if getattr(core, n, None) is None]; "
            "print(light, missing, 'regor_ros.core.pipeline' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.stdout.split() == ["True", "[]", "True"], run.stderr


@pytest.mark.parametrize("user_setting", [None, "1000000"])
def test_the_core_keeps_openmp_threads_from_spinning_long_while_they_wait_unless_the_user_said_otherwise(
        user_setting):
    """Set on import, before the kernels load their OpenMP runtime (it reads the setting once)."""
    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"}
    if user_setting:
        env["GOMP_SPINCOUNT"] = user_setting
    code = ("import os, sys, regor_ros.core; "
            "print(os.environ.get('GOMP_SPINCOUNT'), 'numba' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert run.stdout.split() == [user_setting or "10000", "False"], run.stderr


def test_a_node_left_running_is_killed_and_named():
    """What the suite does with a register_node a test left running (conftest.py)."""
    from types import SimpleNamespace

    from ros_helpers import kill_survivors
    running = SimpleNamespace(proc=subprocess.Popen(["sleep", "600"]))
    finished = SimpleNamespace(proc=subprocess.Popen(["true"]))
    finished.proc.wait(timeout=10)
    assert kill_survivors([running, finished]) == [running]
    assert running.proc.poll() is not None


def test_the_type_checkers_stub_names_every_public_name_from_its_home():
    """To a type checker the lazy core's names are what they are, not Any: __init__.pyi imports each
    from its home, as regor_ros.core.public_stub() writes it."""
    import regor_ros.core as core
    stub = Path(core.__file__).with_name("__init__.pyi")
    assert stub.read_text() == core.public_stub(), \
        "regenerate: python -c \"import regor_ros.core as c; open(c.__file__ + 'i', 'w').write(c.public_stub())\""
    assert all(f"    {name} as {name}," in stub.read_text() for name in core.__all__)
