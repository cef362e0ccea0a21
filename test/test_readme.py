"""The README's pip-route commands, run as written (the relocalization workflow on the bundled
example): a fresh clone's user has no ros2 command, only what scripts/setup.sh installs."""
import os
import re
import subprocess

from conftest import REPO


def _block(name: str) -> str:
    text = (REPO / "README.md").read_text()
    match = re.search(rf"<!-- {name} -->\s*```bash\n(.*?)```", text, re.S)
    assert match, f"the README has no '{name}' block"
    return match.group(1)


def test_the_pip_route_relocalizes_in_a_saved_map_as_the_readme_says(install):
    """Run in the repository (the commands use its relative paths) with the test's own colcon
    install as ``install/`` and its tools on PATH, as scripts/setup.sh puts them."""
    commands = _block("pip route: relocalize")
    script = "set -euo pipefail\n" + commands.replace("install/", f"{install}/")
    env = {**os.environ, "PATH": f"{install}/regor_ros/lib/regor_ros{os.pathsep}{os.environ['PATH']}"}
    result = subprocess.run(["bash", "-c", f"source {install}/setup.bash\n{script}\nwait %1 || true"],
                            cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    out = result.stdout + result.stderr
    assert result.returncode == 0, out
    assert "relocalize: accepted" in out and "pose in 'map'" in out, out
    assert "load_map demo/tgt.npy: map loaded" in out, out
    assert "deactivate: done" in out, out
