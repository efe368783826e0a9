"""Execute a RunPlan: start every node as its own process, follow the stages'
status topics, collect the latched outputs and hand them to the results writer."""
from __future__ import annotations

import time

import rclpy
from rclpy.node import Node
from yowo_msgs.msg import ReplayStatus, StageStatus

from yowo_common.ros.bag import message_class
from yowo_common.ros.context import ros_context
from yowo_common import topics
from yowo_common.ros.stage import LATCHED

from .run import RunOutcome, RunPlan, write_run_results
from .supervisor import Supervisor, write_params_file

# After the final stage finished, time for the latched outputs to arrive: a stage that
# succeeded published them all (a loaded machine took > 2 s to deliver the map clouds);
# after a failure some never come.
GRACE_S = {"done": 30.0, "failed": 2.0}


class RunFailed(RuntimeError):
    pass


class RunMonitor(Node):
    def __init__(self, stages: list[str], outputs: dict[str, str]):
        super().__init__("yowo_run")
        self.status: dict[str, StageStatus] = {}
        self.replay: ReplayStatus | None = None
        self.outputs: dict[str, object] = {}
        for s in stages:
            self.create_subscription(StageStatus, topics.status(s), lambda m, s=s: self.status.__setitem__(s, m),
                                     LATCHED)
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay, LATCHED)
        self._relay = None
        for topic, msgtype in outputs.items():
            self.create_subscription(message_class(msgtype), topic,
                                     lambda m, t=topic: self.outputs.__setitem__(t, m), LATCHED)

    def _on_replay(self, msg: ReplayStatus) -> None:
        self.replay = msg

    def relay_end_of_walk(self) -> None:
        """Live runs: keep `yowo end-walk`'s announcement latched for the rest of the run,
        so a stage whose subscription matches after the announcer left still gets it."""
        if self._relay is None and self.replay is not None and self.replay.state == ReplayStatus.STATE_FINISHED:
            self._relay = self.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED)
            self._relay.publish(self.replay)

    def finished(self, stage: str) -> StageStatus | None:
        msg = self.status.get(stage)
        return msg if msg is not None and msg.state != StageStatus.STATE_RUNNING else None

    def progress(self, stages: list[str]) -> str:
        played = sum(self.replay.published_counts) if self.replay else 0
        done = [s for s in stages if self.finished(s)]
        return f"replayed {played} messages; stages done {len(done)}/{len(stages)}"


def execute(plan: RunPlan, timeout_s: float = 3600.0, log=print, env: dict | None = None,
            linger_s: float = 0.0) -> RunOutcome:
    """Run the graph and write the results directory. Raises RunFailed with the reason
    (after writing whatever partial results exist). `linger_s`: after a successful run,
    keep the graph up this long with the results written (late /tf_static subscribers)."""
    plan.out_dir.mkdir(parents=True, exist_ok=True)
    params_file = plan.out_dir / "params.yaml"
    write_params_file(plan.nodes, params_file)
    sup = Supervisor(plan.out_dir / "logs", env)
    stages = [n.name for n in plan.nodes if n.name != "replay"]
    t0 = time.monotonic()
    failure, outcome = "", None
    with ros_context([]):
        monitor = RunMonitor(stages, plan.outputs)
        try:
            for spec in plan.nodes:  # replay last: it waits for the stages' subscriptions
                sup.start(spec, params_file)
            last_report, finished_at = 0.0, None
            while True:
                rclpy.spin_once(monitor, timeout_sec=0.1)
                if plan.bag is None:
                    monitor.relay_end_of_walk()
                dead = sup.dead()
                if dead:
                    p = dead[0]
                    failure = (f"node '{p.spec.name}' died (exit {p.popen.returncode}); last log lines:\n"
                               f"{p.log_tail()}")
                    break
                final = monitor.finished(plan.final_stage)
                if final is not None and finished_at is None:
                    finished_at = time.monotonic()
                grace = GRACE_S["failed" if final is not None and final.state == StageStatus.STATE_FAILED else "done"]
                if finished_at is not None and (all(t in monitor.outputs for t in plan.outputs)
                                                or time.monotonic() - finished_at > grace):
                    if final.state == StageStatus.STATE_FAILED:
                        failure = f"stage '{plan.final_stage}' failed: {final.message}"
                    break
                if time.monotonic() - t0 > timeout_s:
                    failure = (f"no result after {timeout_s:.0f} s; "
                               + ", ".join(f"{s}={'done' if monitor.finished(s) else 'running'}" for s in stages))
                    break
                if time.monotonic() - last_report > 5.0:
                    last_report = time.monotonic()
                    log(f"[{time.monotonic() - t0:6.1f} s] {monitor.progress(stages)}")
            if linger_s > 0 and not failure:
                outcome = write_run_results(plan, dict(monitor.outputs), dict(monitor.status), monitor.replay,
                                            time.monotonic() - t0, failure)
                log(f"results written to {plan.out_dir}; the graph stays up {linger_s:.0f} s (latched /tf_static)")
                end = time.monotonic() + linger_s
                while time.monotonic() < end and not sup.dead():
                    rclpy.spin_once(monitor, timeout_sec=0.1)
        finally:
            outputs, status, replay = dict(monitor.outputs), dict(monitor.status), monitor.replay
            monitor.destroy_node()
            sup.stop()
    if outcome is None:
        outcome = write_run_results(plan, outputs, status, replay, time.monotonic() - t0, failure)
    if failure:
        raise RunFailed(failure)
    return outcome


def end_walk(linger_s: float = 5.0) -> None:
    """Live operation: announce the end of the walk (what a replay does at the end of a
    recording), so every stage finalises with what it has received."""
    from yowo_common.ros.stage import REPLAY

    with ros_context([]):
        node = Node("yowo_end_walk")
        pub = node.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED)
        pub.publish(ReplayStatus(state=ReplayStatus.STATE_FINISHED, bag=f"live ({REPLAY} not used)"))
        # Latched: stages that match while we linger still get it. Discovery on a busy
        # machine takes seconds, so the linger starts once a first stage has matched.
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        end = time.monotonic() + linger_s
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        node.destroy_node()
