"""Which DDS domain a run's graph lives on. A run on a recording is private by default:
a ROS domain that no other YOWO run on this host holds (an exclusive lock on
/tmp/yowo-ros-domain-<id>.lock, released by the kernel when the run's process ends)
and where no DDS participant of anybody else listens (its discovery ports are free),
with localhost-only discovery. Live runs and split multi-host runs share the user's
domain. No rclpy here: the environment is set before the DDS starts."""

from __future__ import annotations

import fcntl
import os
import random
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

# ROS 2's domain ids on Linux (Fast DDS / Cyclone port mapping: 7400 + 250 * id).
MAX_DOMAIN_ID = 232
PRIVATE, SHARED = "private", "shared"
# RTPS well-known ports (DDSI-RTPS 9.6.1.1): discovery multicast PB + DG * d, and the
# discovery unicast of participant i at PB + DG * d + d1 + PG * i.
_PB, _DG, _PG, _D1, _PARTICIPANTS_PROBED = 7400, 250, 2, 10, 24


class NoFreeDomain(RuntimeError):
    pass


def _lock_path(domain: int) -> Path:
    return Path(tempfile.gettempdir()) / f"yowo-ros-domain-{domain}.lock"


def _udp_port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def domain_in_use(domain: int) -> bool:
    """A DDS participant of this domain runs on this host (it holds the domain's discovery
    multicast port or one of its first participants' unicast ports)."""
    base = _PB + _DG * domain
    ports = [base] + [base + _D1 + _PG * i for i in range(_PARTICIPANTS_PROBED)]
    return not all(_udp_port_free(p) for p in ports)


@dataclass
class GraphNetwork:
    """The DDS settings of a run: the environment of its processes and what the user is told."""

    domain_id: int
    private: bool
    discovery: str  # ROS_AUTOMATIC_DISCOVERY_RANGE in effect
    env: dict = field(repr=False, default_factory=dict)
    _lock_fd: int | None = field(default=None, repr=False)

    def describe(self) -> str:
        if self.private:
            return (
                f"private ROS domain {self.domain_id}, discovery {self.discovery.lower()} only "
                "(--domain shared to join your ROS graph)"
            )
        return f"ROS_DOMAIN_ID={self.domain_id}, discovery range {self.discovery.lower()}"

    def release(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None


def claim_private_domain(
    exclude: set[int] = frozenset(), candidates: range = range(1, MAX_DOMAIN_ID + 1), rng: random.Random | None = None
) -> tuple[int, int]:
    """(domain id, lock fd): a domain no YOWO run on this host holds and nobody's DDS
    listens on; the lock is held until the fd is closed or the process ends."""
    domains = [d for d in candidates if d not in exclude]
    (rng or random.Random()).shuffle(domains)
    for domain in domains:
        try:
            fd = os.open(_lock_path(domain), os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            continue  # another user's lock file
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        if domain_in_use(domain):
            os.close(fd)
            continue
        return domain, fd
    raise NoFreeDomain(
        f"no free ROS domain on this host: all of {candidates.start}-{candidates.stop - 1} are "
        "held by other YOWO runs or used by other DDS participants"
    )


def graph_network(domain: str | int = PRIVATE, base_env: dict | None = None) -> GraphNetwork:
    """`private`: a fresh domain with localhost-only discovery; `shared`: the user's
    ROS_DOMAIN_ID and discovery settings; an int: that domain, the user's discovery range."""
    env = dict(os.environ if base_env is None else base_env)
    user_domain = int(env.get("ROS_DOMAIN_ID") or 0)
    if domain == PRIVATE:
        domain_id, fd = claim_private_domain(exclude={user_domain})
        env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("ROS_STATIC_PEERS", None)
        return GraphNetwork(domain_id, True, "LOCALHOST", env, fd)
    domain_id = user_domain if domain == SHARED else int(domain)
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS domain {domain_id} is outside 0-{MAX_DOMAIN_ID}")
    env["ROS_DOMAIN_ID"] = str(domain_id)
    return GraphNetwork(domain_id, False, env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") or "SUBNET", env)
