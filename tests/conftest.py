import subprocess
import sys
from pathlib import Path

import pytest

from yowo_bringup.ros_domain import PRIVATE, graph_network

GRAPH = Path(__file__).parent / "graph"


@pytest.fixture
def ros_env():
    """An environment with a DDS domain of its own (claimed as `yowo run` claims a private
    one), so concurrent test runs (other checkouts, CI next to development) never
    cross-talk; the graph verbs inside a test claim private domains of their own."""
    network = graph_network(PRIVATE)
    yield network.env
    network.release()


@pytest.fixture
def start_script(ros_env):
    """Start a tests/graph script in its own process; every process is reaped at teardown."""
    procs = []

    def start(name, *args):
        p = subprocess.Popen(
            [sys.executable, str(GRAPH / name), *map(str, args)],
            env=ros_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(p)
        return p

    yield start
    for p in procs:
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:  # hung in the middleware, where no signal handler runs
                p.kill()
                p.wait(timeout=10)
