"""The scripts in examples/ run as a user would run them, and do what they say."""
import os
import subprocess
import sys
from pathlib import Path


EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _run(name: str) -> str:
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    res = subprocess.run([sys.executable, str(EXAMPLES / name)], capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout


def test_hybrid_tracking_example_needs_no_initial_pose():
    out = _run("hybrid_tracking.py").splitlines()
    assert out[0].split()[1] == "init" and "lost" in " ".join(out)
    assert "frames with a trusted pose" in out[-1]


def test_custom_backend_example_goes_lost_in_the_eclipse_and_comes_back():
    statuses = [line.split()[3] for line in _run("custom_backend.py").splitlines()]
    first_lost = statuses.index("lost")
    assert statuses[-1] == "tracking" and "lost" not in statuses[first_lost:][statuses[first_lost:].index("tracking"):]
