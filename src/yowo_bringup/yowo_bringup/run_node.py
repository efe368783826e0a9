"""Execute a RunPlan: start every node as its own process, follow the stages'
status topics, collect the outputs and write the results directory."""
from __future__ import annotations

import time

import rclpy
import yaml
from rclpy.node import Node
from yowo_msgs.msg import CameraGroupArray, ReplayStatus, StageStatus

from yowo_cmc.group_sfm_node import GROUPS_TOPIC
from yowo_cmc.messages import groups_from_msg
from yowo_common.ros.context import ros_context
from yowo_common.ros.stage import LATCHED, REPLAY_STATUS_TOPIC, status_topic

from .run import RunPlan, read_intrinsics, write_group_calibration
from .supervisor import Supervisor, write_params_file


class RunFailed(RuntimeError):
    pass


class RunMonitor(Node):
    def __init__(self, stages: list[str]):
        super().__init__("yowo_run")
        self.status: dict[str, StageStatus] = {}
        self.replay: ReplayStatus | None = None
        self.groups: CameraGroupArray | None = None
        for s in stages:
            self.create_subscription(StageStatus, status_topic(s), lambda m, s=s: self.status.__setitem__(s, m),
                                     LATCHED)
        self.create_subscription(ReplayStatus, REPLAY_STATUS_TOPIC, lambda m: setattr(self, "replay", m), LATCHED)
        self.create_subscription(CameraGroupArray, GROUPS_TOPIC, lambda m: setattr(self, "groups", m), LATCHED)

    def finished(self, stage: str) -> StageStatus | None:
        msg = self.status.get(stage)
        return msg if msg is not None and msg.state != StageStatus.STATE_RUNNING else None


def execute(plan: RunPlan, timeout_s: float = 3600.0, log=print, env: dict | None = None) -> dict:
    """Run the graph; returns a summary dict. Raises RunFailed with the reason."""
    plan.out_dir.mkdir(parents=True, exist_ok=True)
    params_file = plan.out_dir / "params.yaml"
    write_params_file(plan.nodes, params_file)
    sup = Supervisor(plan.out_dir / "logs", env)
    stages = [n.name for n in plan.nodes if n.name != "replay"]
    t0 = time.monotonic()
    with ros_context([]):
        monitor = RunMonitor(stages)
        try:
            for spec in plan.nodes:  # replay last: it waits for the stages' subscriptions
                sup.start(spec, params_file)
            last_report = 0.0
            while True:
                rclpy.spin_once(monitor, timeout_sec=0.1)
                dead = sup.dead()
                if dead:
                    p = dead[0]
                    raise RunFailed(f"node '{p.spec.name}' died (exit {p.popen.returncode}); last log lines:\n"
                                    f"{p.log_tail()}")
                final = monitor.finished(plan.final_stage)
                if final is not None and (final.state == StageStatus.STATE_FAILED or monitor.groups is not None):
                    break
                if time.monotonic() - t0 > timeout_s:
                    raise RunFailed(f"no result after {timeout_s:.0f} s; stages: "
                                    + ", ".join(f"{s}={'done' if monitor.finished(s) else 'running'}" for s in stages))
                if time.monotonic() - last_report > 5.0:
                    last_report = time.monotonic()
                    done = sum(1 for s in stages if monitor.finished(s))
                    played = sum(monitor.replay.published_counts) if monitor.replay else 0
                    log(f"[{time.monotonic() - t0:6.1f} s] replayed {played} messages; {done}/{len(stages)} stages done")
            if final.state == StageStatus.STATE_FAILED:
                raise RunFailed(f"stage '{plan.final_stage}' failed: {final.message}")
            groups, ungrouped = groups_from_msg(monitor.groups)
        finally:
            monitor.destroy_node()
            sup.stop()
    write_group_calibration(plan.out_dir / "cameras.yaml", groups, ungrouped, read_intrinsics(plan.bag, plan.cameras))
    summary = {s: monitor.status[s].message for s in stages if s in monitor.status}
    counts = {}
    if monitor.replay is not None:
        counts = dict(zip(monitor.replay.topics, monitor.replay.published_counts))
    received = {}
    for s, msg in monitor.status.items():
        for t, n in zip(msg.input_topics, msg.received_counts):
            received.setdefault(t, {})[s] = int(n)
    (plan.out_dir / "run_log.yaml").write_text(yaml.safe_dump({
        "bag": str(plan.bag), "seconds": round(time.monotonic() - t0, 2), "warnings": plan.warnings,
        "stages": summary, "replay_published": counts, "received": received}, sort_keys=False))
    return {"groups": groups, "ungrouped": ungrouped, "published": counts, "received": received}
