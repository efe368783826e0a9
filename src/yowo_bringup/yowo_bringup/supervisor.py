"""Start YOWO's nodes as separate processes, keep their logs, notice when one dies,
and stop them all cleanly (SIGINT, then SIGTERM, then SIGKILL)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml


@dataclass
class NodeSpec:
    name: str                      # node (and stage) name
    module: str                    # python module with main(), e.g. "yowo_cmc.group_sfm_node"
    parameters: dict = field(default_factory=dict)


@dataclass
class NodeProcess:
    spec: NodeSpec
    popen: subprocess.Popen
    log_path: Path

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


class _NoAliasDumper(yaml.SafeDumper):
    """rcl's parameter parser does not support YAML aliases (&id001 / *id001)."""

    def ignore_aliases(self, data):
        return True


def write_params_file(specs: list[NodeSpec], path: Path) -> None:
    """One ROS 2 parameter file for every node of the run (kept with the results)."""
    doc = {s.name: {"ros__parameters": s.parameters} for s in specs if s.parameters}
    path.write_text(yaml.dump(doc, Dumper=_NoAliasDumper, sort_keys=False))


class Supervisor:
    def __init__(self, log_dir: Path, env: dict | None = None):
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.env = dict(os.environ if env is None else env)
        self.procs: list[NodeProcess] = []

    def start(self, spec: NodeSpec, params_file: Path | None = None) -> NodeProcess:
        cmd = [sys.executable, "-m", spec.module, "--ros-args", "-r", f"__node:={spec.name}"]
        if params_file is not None and spec.parameters:
            cmd += ["--params-file", str(params_file)]
        log_path = self.log_dir / f"{spec.name}.log"
        with open(log_path, "w") as log:
            popen = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                     start_new_session=True)  # our own Ctrl-C handling stops them in order
        (self.log_dir / f"{spec.name}.pid").write_text(f"{popen.pid}\n")  # for users and tests
        proc = NodeProcess(spec, popen, log_path)
        self.procs.append(proc)
        return proc

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
                return
