import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

GRAPH = Path(__file__).parent / "graph"


@pytest.fixture
def ros_env():
    """An environment with a DDS domain of its own, so concurrent test runs do not cross-talk."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(random.Random().randint(1, 100))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


@pytest.fixture
def start_script(ros_env):
    """Start a tests/graph script in its own process; every process is reaped at teardown."""
    procs = []

    def start(name, *args):
        p = subprocess.Popen([sys.executable, str(GRAPH / name), *map(str, args)], env=ros_env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(p)
        return p

    yield start
    for p in procs:
        if p.poll() is None:
            p.terminate()
            p.wait(timeout=10)
