"""Start YOWO's nodes as separate processes, keep their logs, restart one that dies
(its `incarnation` parameter counts the restarts, so the replay and the upstream stages
send it what it missed), and stop them all cleanly (SIGINT, then SIGTERM, then SIGKILL)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from yowo_common.ros.context import NODES_ARG

from .profiling import NodeProfiler, py_spy


@dataclass(kw_only=True)
class NodeSpec:
    name: str  # node (and stage) name; of a process hosting several: the process's
    module: str  # python module with main(), e.g. "yowo_cmc.group_sfm_node"
    parameters: dict = field(default_factory=dict)
    niceness: int = 0  # added to the supervisor's own (a lower priority)
    hosted: list[str] = field(default_factory=list)  # the nodes one process runs (their parameters
    # in the params file); empty: this node alone

    @property
    def nodes(self) -> list[str]:
        return self.hosted or [self.name]


@dataclass
class Usage:
    """A node process's resources as /proc last showed them (sampled while it runs:
    a reaped process has none left to read)."""

    cpu_s: float = 0.0  # user + system
    peak_rss_mb: float = 0.0  # VmHWM
    started: float = field(default_factory=time.monotonic)
    spawned: float = field(default_factory=time.time)  # wall clock, as the nodes' timing files
    last_seen: float = 0.0

    @staticmethod
    def read(pid: int) -> tuple[float, float] | None:
        """(cpu seconds, peak RSS MB) of a live process, None when it is gone."""
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            return None
        fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)"
        cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        return cpu, _proc_mb(status, "VmHWM:")

    @staticmethod
    def pss_mb(pid: int) -> float:
        """A live process's proportional set size now (MB; 0 when it is gone). The kernel
        walks every mapping for it: ~9 ms for a 1 GB node, so it is sampled less often."""
        try:
            rollup = Path(f"/proc/{pid}/smaps_rollup").read_text()
        except OSError:
            return 0.0
        return _proc_mb(rollup, "Pss:")


def _proc_mb(text: str, key: str) -> float:
    """A "<key> <n> kB" line of a /proc file, in MB (0 without it)."""
    return next((int(line.split()[1]) for line in text.splitlines() if line.startswith(key)), 0) / 1024.0


@dataclass(kw_only=True)
class NodeProcess:
    spec: NodeSpec
    popen: subprocess.Popen
    log_path: Path
    incarnation: int = 0
    exits: list[int] = field(default_factory=list)  # exit codes of earlier incarnations
    usage: list[Usage] = field(default_factory=lambda: [Usage()])  # one per incarnation

    def sample(self) -> None:
        got = Usage.read(self.popen.pid) if self.popen.poll() is None else None
        if got is not None:
            u = self.usage[-1]
            u.cpu_s, u.peak_rss_mb, u.last_seen = got[0], max(u.peak_rss_mb, got[1]), time.monotonic()

    def resources(self) -> dict:
        """CPU seconds (summed over incarnations), wall seconds alive, peak RSS."""
        return {
            "cpu_s": round(sum(u.cpu_s for u in self.usage), 2),
            "wall_s": round(sum(max(u.last_seen - u.started, 0.0) for u in self.usage), 2),
            "peak_rss_mb": round(max(u.peak_rss_mb for u in self.usage), 1),
        }

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


LIBRARY_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def library_threads_env(env: dict, threads: int) -> dict:
    """``env`` with each numeric library's thread count set to ``threads`` (0: unchanged)."""
    return {**env, **{k: str(threads) for k in LIBRARY_THREAD_VARIABLES}} if threads > 0 else dict(env)


class _NoAliasDumper(yaml.SafeDumper):
    """rcl's parameter parser does not support YAML aliases (&id001 / *id001), and it types a
    plain scalar by its look, more eagerly than YAML: the run id 138531451e07 became a double
    and the replay refused it. Every string is written quoted."""

    def ignore_aliases(self, data):
        return True

    def represent_str(self, data):
        return self.represent_scalar("tag:yaml.org,2002:str", data, style='"')


_NoAliasDumper.add_representer(str, _NoAliasDumper.represent_str)


def write_params_file(specs: list[NodeSpec], path: Path) -> None:
    """One ROS 2 parameter file for every node of the run (kept with the results)."""
    doc = {s.name: {"ros__parameters": s.parameters} for s in specs if s.parameters}
    path.write_text(yaml.dump(doc, Dumper=_NoAliasDumper, sort_keys=False))


def stats_path(log_dir: Path, name: str, incarnation: int) -> Path:
    """Where a node process writes its timing (yowo_common.ros.timing)."""
    return Path(log_dir) / (f"{name}.stats.yaml" if not incarnation else f"{name}.{incarnation}.stats.yaml")


class Supervisor:
    """`profile_dir`: record every node process with py-spy there (`profile_rate_hz`)."""

    def __init__(
        self,
        log_dir: Path,
        env: dict | None = None,
        params_file: Path | None = None,
        profile_dir: Path | None = None,
        profile_rate_hz: int = 50,
    ):
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.env = dict(os.environ if env is None else env)
        self.params_file = params_file
        self.procs: list[NodeProcess] = []
        # The graph's memory: the largest sum of the node processes' and this process's PSS
        # at one sample. Peak RSS per process counts the shared libraries in every process
        # and peaks that came at different times, so their sum overstates a many-node graph.
        self.peak_memory_mb = 0.0
        self.peak_memory_by_process: dict[str, float] = {}  # each process's PSS at that sample
        self.profile_dir, self.profile_rate_hz = profile_dir, profile_rate_hz
        self.profilers: list[NodeProfiler] = []
        if profile_dir is not None:
            py_spy()  # says so before any node starts when it is not installed
            Path(profile_dir).mkdir(parents=True, exist_ok=True)

    def _popen(self, spec: NodeSpec, incarnation: int, mode: str) -> subprocess.Popen:
        # -P: the folder the user started in is not on the node's import path, so no file
        # there can stand in for a module the node imports.
        if spec.hosted:
            cmd = [sys.executable, "-P", "-m", spec.module, NODES_ARG, ",".join(spec.hosted), "--ros-args"]
        else:
            cmd = [sys.executable, "-P", "-m", spec.module, "--ros-args", "-r", f"__node:={spec.name}"]
        if self.params_file is not None and (spec.parameters or spec.hosted):
            cmd += ["--params-file", str(self.params_file)]
        if incarnation:
            cmd += ["-p", f"incarnation:={incarnation}"]
        cmd += ["-p", f"stats_file:={stats_path(self.log_dir, '{node}' if spec.hosted else spec.name, incarnation)}"]
        if spec.niceness:  # nice execs the node: the same process, every thread of it
            cmd = ["nice", "-n", str(spec.niceness)] + cmd
        with open(self.log_dir / f"{spec.name}.log", mode) as log:
            if incarnation:
                log.write(f"--- [yowo supervisor] restarted (incarnation {incarnation}) ---\n")
                log.flush()
            popen = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=self.env, start_new_session=True
            )  # our own Ctrl-C handling stops them in order
        for name in {spec.name, *spec.nodes}:  # for users and tests, also per hosted node
            (self.log_dir / f"{name}.pid").write_text(f"{popen.pid}\n")
        if self.profile_dir is not None:
            stem = spec.name if not incarnation else f"{spec.name}.{incarnation}"
            self.profilers.append(NodeProfiler(popen.pid, Path(self.profile_dir) / f"{stem}.txt", self.profile_rate_hz))
        return popen

    def start(self, spec: NodeSpec) -> NodeProcess:
        proc = NodeProcess(spec=spec, popen=self._popen(spec, 0, "w"), log_path=self.log_dir / f"{spec.name}.log")
        self.procs.append(proc)
        return proc

    def restart(self, proc: NodeProcess) -> None:
        """Start a dead node again as its next incarnation (its log continues)."""
        proc.exits.append(proc.popen.returncode)
        proc.incarnation += 1
        proc.popen = self._popen(proc.spec, proc.incarnation, "a")
        proc.usage.append(Usage())

    def sample(self, memory: bool = True) -> None:
        """Every process's CPU and peak RSS; with `memory`, also the graph's memory now."""
        for p in self.procs:
            p.sample()
        if memory:
            now = {p.spec.name: Usage.pss_mb(p.popen.pid) for p in self.procs if p.popen.poll() is None}
            now["supervisor"] = Usage.pss_mb(os.getpid())
            total = sum(now.values())
            if total > self.peak_memory_mb:
                self.peak_memory_mb, self.peak_memory_by_process = total, now

    def dead(self) -> list[NodeProcess]:
        """Processes that exited with an error."""
        return [p for p in self.procs if p.popen.poll() not in (None, 0)]

    def stop(self, timeout_s: float = 10.0) -> None:
        alive = [p for p in self.procs if p.popen.poll() is None]
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            for p in alive:
                try:
                    p.popen.send_signal(sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline and any(p.popen.poll() is None for p in alive):
                time.sleep(0.05)
            alive = [p for p in alive if p.popen.poll() is None]
            if not alive:
                break
        for profiler in self.profilers:  # each writes its recording once its node has ended
            profiler.wait(timeout_s)
