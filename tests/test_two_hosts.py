"""The graph split across two hosts: two network namespaces joined by a veth pair stand
in for them (replay and trackers on one, ego mapper, group SfM and fusion on the other),
talking over UDP only. The result equals the one-host run's, byte for byte."""

import os
import shutil
import subprocess
import sys

import pytest
import yaml

from e2e_helpers import yowo
from yowo_bringup.ros_domain import PRIVATE, graph_network
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


def _ip(*args):
    return subprocess.run(["ip", *args], capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    """Names of two network namespaces on one link (10.77.<n>.1 and .2), removed afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("two-host test: the 'ip' command (iproute2) is not installed")
    tag = f"{os.getpid() % 10000}"
    a, b, link = f"yowo-a{tag}", f"yowo-b{tag}", f"yv{tag}"
    made = _ip("netns", "add", a)
    if made.returncode != 0:
        pytest.skip(f"two-host test: this machine does not allow network namespaces ({made.stderr.strip()})")
    try:
        assert _ip("netns", "add", b).returncode == 0
        subnet = f"10.77.{os.getpid() % 250}"
        for cmd in (
            ["link", "add", f"{link}a", "type", "veth", "peer", "name", f"{link}b"],
            ["link", "set", f"{link}a", "netns", a],
            ["link", "set", f"{link}b", "netns", b],
            ["-n", a, "addr", "add", f"{subnet}.1/24", "dev", f"{link}a"],
            ["-n", b, "addr", "add", f"{subnet}.2/24", "dev", f"{link}b"],
        ):
            r = _ip(*cmd)
            assert r.returncode == 0, (cmd, r.stderr)
        for ns, dev in ((a, f"{link}a"), (b, f"{link}b")):
            for cmd in (
                ["-n", ns, "link", "set", "lo", "up"],
                ["-n", ns, "link", "set", dev, "up"],
                ["-n", ns, "route", "add", "224.0.0.0/4", "dev", dev],
            ):  # DDS discovery multicast
                r = _ip(*cmd)
                assert r.returncode == 0, (cmd, r.stderr)
        yield a, b, f"{link}a"
    finally:
        _ip("netns", "del", a)
        _ip("netns", "del", b)


def test_graph_split_across_two_hosts_equals_one_host_run(tmp_path, ros_env, two_hosts):
    host_a, host_b, link_a = two_hosts
    bag = tmp_path / "tiny_s5"
    generate(get_preset("tiny"), 5, bag)
    one = tmp_path / "one_host"
    r = yowo("run", bag, "-o", one, env=ros_env, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    # One domain for both hosts (claimed here so no other run on this machine takes it),
    # discovery beyond localhost, and no shared-memory transport: only the network.
    network = graph_network(PRIVATE)
    env = {k: v for k, v in ros_env.items() if k not in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID")}
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    common = ["--domain", str(network.domain_id), "--run-id", "split-test", "--timeout", "400"]
    cli = [sys.executable, "-m", "yowo_bringup.cli", "run", str(bag)]
    try:
        a = subprocess.Popen(
            [
                "ip",
                "netns",
                "exec",
                host_a,
                *cli,
                "-o",
                str(tmp_path / "host_a"),
                *common,
                "--nodes",
                "replay",
                "keypoint_tracker_*",
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        b = subprocess.run(
            [
                "ip",
                "netns",
                "exec",
                host_b,
                *cli,
                "-o",
                str(tmp_path / "host_b"),
                *common,
                "--nodes",
                "ego_mapper",
                "group_sfm",
                "fusion",
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=500,
        )
        a_out, a_err = a.communicate(timeout=120)
    finally:
        network.release()
    assert b.returncode == 0, b.stdout[-3000:] + b.stderr[-3000:]
    assert a.returncode == 0, a_out[-3000:] + a_err[-3000:]
    log_a = yaml.safe_load((tmp_path / "host_a" / "run_log.yaml").read_text())
    log_b = yaml.safe_load((tmp_path / "host_b" / "run_log.yaml").read_text())
    assert sorted(log_a["graph"]["nodes_on_this_host"]) == [
        "keypoint_tracker_cam00",
        "keypoint_tracker_cam01",
        "keypoint_tracker_cam02",
        "replay",
    ]
    assert sorted(log_b["graph"]["nodes_on_this_host"]) == ["ego_mapper", "fusion", "group_sfm"]
    # The ego images crossed the link (they are most of the recording).
    stats = subprocess.run(["ip", "-n", host_a, "-s", "-j", "link", "show", link_a], capture_output=True, text=True)
    sent = yaml.safe_load(stats.stdout)[0]["stats64"]["tx"]["bytes"]
    assert sent > 0.5 * sum(f.stat().st_size for f in bag.glob("*.mcap")), sent
    for name in ("cameras.yaml", "ego_trajectory.tum", "layout.json"):
        assert (tmp_path / "host_b" / name).read_bytes() == (one / name).read_bytes(), name
        assert (tmp_path / "host_a" / name).read_bytes() == (one / name).read_bytes(), name
