import fcntl
import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

GRAPH = Path(__file__).parent / "graph"


@pytest.fixture
def ros_env():
    """An environment with a DDS domain of its own, so concurrent test runs (other
    checkouts, CI next to development) never cross-talk: the domain is claimed with
    an exclusive lock on /tmp/yowo-ros-domain-<id>.lock, held for the test and
    released by the kernel even if the test process dies."""
    domains = list(range(1, 101))
    random.Random().shuffle(domains)
    for domain in domains:
        lock = open(f"/tmp/yowo-ros-domain-{domain}.lock", "w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.close()
            continue
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        yield env
        lock.close()
        return
    pytest.fail("every ROS domain 1-100 is locked by other test runs")


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
