"""Execute a RunPlan: start every node as its own process, follow the stages'
status topics, collect the latched outputs and hand them to the results writer."""

from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from yowo_common import topics
from yowo_common.ros.context import ros_context
from yowo_common.ros.timing import relative_to
from yowo_msgs.msg import ReplayStatus, StageStatus

from .config import CONFIG_PARAMETERS, params_document
from .guidance import guidance_log
from .profiling import summary_markdown
from .progress import ProgressLines, record_final_steps
from .ros_domain import PRIVATE, GraphNetwork, graph_network
from .run import RunPlan
from .run_monitor_node import RunMonitor
from .run_results import RunOutcome, write_run_results
from .supervisor import Supervisor, library_threads_env, stats_path, write_params_file

# After the final stage finished, time for the latched outputs and every stage's last status
# to arrive: a stage that succeeded published them all (a loaded machine took seconds to
# deliver the map clouds, and a tracker's last status came after the group SfM's failure);
# after a failure some outputs never come.
GRACE_S = {"done": 30.0, "failed": 10.0}
# How often the supervisor samples the node processes' CPU and peak RSS, and the graph's memory
# (the PSS of every process: the kernel walks each one's mappings, which takes a while for a large node).
SAMPLE_S, MEMORY_SAMPLE_S = 1.0, 5.0
# What decides which DDS graph a process joins.
DDS_ENV = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS")


class RunFailed(RuntimeError):
    pass


def execute(
    plan: RunPlan,
    timeout_s: float = 3600.0,
    log=print,
    network: GraphNetwork | None = None,
    linger_s: float = 0.0,
    progress=None,
    profile_dir: Path | None = None,
    guidance=None,
) -> RunOutcome:
    """Run the graph (the plan's local nodes; the others run on other hosts) and write the
    results directory. Raises RunFailed with the reason (after writing whatever partial
    results exist). `network`: the run's DDS domain (a private one by default);
    `linger_s`: after a successful run, keep the graph up this long with the results
    written (late /tf_static subscribers); `progress`: called with a RunProgress several
    times a second (default: a line every 5 s through `log`); `profile_dir`: a py-spy
    recording of every node process there and summary.md, their top functions; `guidance`:
    called with the newest walk guidance (yowo_msgs/WalkGuidance) whenever one arrives."""
    progress = progress or ProgressLines(log)
    network = network or graph_network(PRIVATE)
    sup = Supervisor(
        plan.out_dir / "logs",
        library_threads_env(network.env, plan.config.supervisor.library_threads),
        _write_parameters(plan),
        profile_dir,
        plan.config.supervisor.profile_rate_hz,
    )
    t0, t0_wall = time.monotonic(), time.time()
    failure, outcome = "", None
    collected = _Collected(outputs={}, status={}, replay=None, graph={})
    with _dds_environment(network):
        # Ctrl-C (and SIGTERM) as KeyboardInterrupt, not rclpy's shutdown: the nodes are stopped
        # and the run log says the run was interrupted.
        with ros_context([], signal_handlers=False), _interrupted(lambda: time.monotonic() - t0) as stop:
            monitor = RunMonitor(plan.stages, plan.outputs, plan.run_id, plan.streams)
            try:
                for spec in plan.local_processes:  # replay last: it waits for the stages' subscriptions
                    sup.start(spec)
                failure = _follow(plan, monitor, sup, log, progress, t0, timeout_s, guidance)
                if not failure and plan.bag is not None:  # the next runs' ETA (a live walk has no length)
                    monitor.progress(plan.stages, time.monotonic() - t0, plan.replay_messages)  # the last ends
                    record_final_steps(monitor.final_steps(), plan.replay_messages)
                if linger_s > 0 and not failure:
                    outcome = write_run_results(
                        plan,
                        dict(monitor.outputs),
                        dict(monitor.status),
                        monitor.replay,
                        time.monotonic() - t0,
                        failure,
                        _graph_log(plan, network, sup, monitor, t0_wall),
                    )
                    log(f"results written to {plan.out_dir}; the graph stays up {linger_s:.0f} s (latched /tf_static)")
                    end = time.monotonic() + linger_s
                    while time.monotonic() < end and not sup.dead():
                        monitor.spin_once(0.1)
            finally:
                sup.sample()
                collected = _Collected(
                    outputs=dict(monitor.outputs),
                    status=dict(monitor.status),
                    replay=monitor.replay,
                    graph=_graph_log(plan, network, sup, monitor, t0_wall),
                )
                monitor.destroy_node()
                sup.stop()
                _write_profiles(plan, sup, profile_dir, log)
    failure = stop.reason or failure
    if outcome is None:
        outcome = write_run_results(
            plan, collected.outputs, collected.status, collected.replay, time.monotonic() - t0, failure, collected.graph
        )
    if outcome.failure:
        raise RunFailed(outcome.failure)
    return outcome


@dataclass(kw_only=True)
class _Collected:
    """What the monitor held when the graph stopped."""

    outputs: dict
    status: dict
    replay: object
    graph: dict


def _write_parameters(plan: RunPlan) -> Path:
    """params.yaml (the resolved tree and each node's own parameters) and the ROS parameter
    file the nodes are started with, whose path is returned."""
    (plan.out_dir / "logs").mkdir(parents=True, exist_ok=True)
    params_file = plan.out_dir / "logs" / "ros_params.yaml"
    write_params_file(plan.nodes, params_file)
    own = {n.name: {k: v for k, v in n.parameters.items() if k not in CONFIG_PARAMETERS} for n in plan.nodes}
    (plan.out_dir / "params.yaml").write_text(yaml.safe_dump(params_document(plan.config, own), sort_keys=False))
    return params_file


@contextlib.contextmanager
def _dds_environment(network: GraphNetwork):
    """This process's own node joins the run's DDS graph; the environment is restored and the
    network released afterwards."""
    saved = {k: os.environ.get(k) for k in DDS_ENV}
    for k in DDS_ENV:
        if k in network.env:
            os.environ[k] = network.env[k]
        else:
            os.environ.pop(k, None)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        network.release()


def _follow(
    plan: RunPlan, monitor: RunMonitor, sup: Supervisor, log, progress, t0: float, timeout_s: float, guidance=None
) -> str:
    """Follow the graph until its final stage has finished and its outputs arrived (or a
    grace period passed), a node cannot be restarted, or the timeout: the failure ('' when
    none)."""
    finished_at, last_sample, last_memory, notes, guided = None, 0.0, 0.0, set(), 0
    while True:
        monitor.spin_once(0.1)
        updates = monitor.outputs.get(topics.GUIDANCE, [])
        if guidance is not None and len(updates) > guided:
            guided = len(updates)
            guidance(updates[-1])
        if plan.bag is None:
            monitor.relay_end_of_walk()
        failure = _restart_dead(sup, plan.config.supervisor.max_restarts, log)
        if failure:
            return failure
        if monitor.replay is not None and monitor.replay.error not in notes | {""}:
            notes.add(monitor.replay.error)
            if monitor.replay.error not in plan.warnings:  # a damaged file is told at the start
                log(f"warning: {monitor.replay.error}")
        final = monitor.finished(plan.final_stage)
        if final is not None and finished_at is None:
            finished_at = time.monotonic()
        failed = final is not None and final.state == StageStatus.STATE_FAILED
        if finished_at is not None and (
            _settled(plan, monitor, failed) or time.monotonic() - finished_at > GRACE_S["failed" if failed else "done"]
        ):
            return _final_failure(plan, monitor, final) if failed else ""
        if time.monotonic() - t0 > timeout_s:
            return f"no result after {timeout_s:.0f} s; " + ", ".join(
                f"{s}={'done' if monitor.finished(s) else 'running'}" for s in plan.stages
            )
        progress(monitor.progress(plan.stages, time.monotonic() - t0, plan.replay_messages))
        for silent in monitor.silent_inputs(time.monotonic() - t0):
            log(f"warning: {silent}")
        if time.monotonic() - last_sample >= SAMPLE_S:
            memory = time.monotonic() - last_memory >= MEMORY_SAMPLE_S
            sup.sample(memory)
            last_sample = time.monotonic()
            last_memory = last_sample if memory else last_memory


def _settled(plan: RunPlan, monitor: RunMonitor, failed: bool) -> bool:
    """Every stage finished, the replay's final status here and (after a success) every output."""
    # The replay's final status too (the run log's counts): on a loaded machine it
    # reached the stages but not yet this node when they had all finished.
    replayed = plan.bag is None or (monitor.replay is not None and monitor.replay.state == ReplayStatus.STATE_FINISHED)
    return (
        replayed
        and all(monitor.finished(s) for s in plan.stages)
        and (failed or all(t in monitor.outputs for t in plan.outputs))
    )


def _final_failure(plan: RunPlan, monitor: RunMonitor, final) -> str:
    # The first cause too: a final stage fails for want of an upstream one's output.
    upstream = [
        f"stage '{s}' failed: {m.message}"
        for s, m in monitor.status.items()
        if s != plan.final_stage and m.state == StageStatus.STATE_FAILED
    ]
    return "; ".join([*upstream, f"stage '{plan.final_stage}' failed: {final.message}"])


def _graph_log(plan: RunPlan, network: GraphNetwork, sup: Supervisor, monitor: RunMonitor, t0_wall: float) -> dict:
    """The run log's account of the graph: network, processes, restarts, resources, timing."""
    return {
        "graph": {
            "run_id": plan.run_id,
            "ros_domain_id": network.domain_id,
            "private": network.private,
            "discovery_range": network.discovery,
            "nodes_on_this_host": [n for p in sup.procs for n in p.spec.nodes],
            "processes": {p.spec.name: p.spec.nodes for p in sup.procs},
            "stray_status_messages": monitor.strays(),
        },
        "restarts": {p.spec.name: p.exits for p in sup.procs if p.exits},
        # Sampled once a second from /proc: the last second of a node is not counted.
        "resources": {p.spec.name: p.resources() for p in sup.procs},
        # The largest sum of every process's proportional set size (this one's included)
        # at one sample: what the graph held of the machine's memory at its peak.
        "peak_memory_mb": round(sup.peak_memory_mb, 1),
        "peak_memory_by_process_mb": {k: round(v, 1) for k, v in sup.peak_memory_by_process.items()},
        # The walk guidance the run monitor received (yowo_msgs/WalkGuidance): how often, what it said last.
        **(
            {
                "guidance": guidance_log(
                    monitor.outputs.get(topics.GUIDANCE, []),
                    monitor.arrivals.get(topics.GUIDANCE, []),
                )
            }
            if topics.GUIDANCE in plan.streams
            else {}
        ),
        # Seconds since the run started; queue waits and handling per input topic.
        "timing": node_timing(sup, t0_wall),
    }


def _write_profiles(plan: RunPlan, sup: Supervisor, profile_dir: Path | None, log) -> None:
    if profile_dir is None:
        return
    (Path(profile_dir) / "summary.md").write_text(summary_markdown(profile_dir, plan.config.supervisor.profile_rate_hz))
    for profiler in sup.profilers:
        if profiler.error:
            log(f"warning: --profile: {profiler.error}")


class _Interruption:
    reason = ""


@contextlib.contextmanager
def _interrupted(elapsed_s):
    """Takes a Ctrl-C (KeyboardInterrupt) and remembers it in `.reason`."""
    stop = _Interruption()
    try:
        yield stop
    except KeyboardInterrupt:
        stop.reason = f"interrupted (Ctrl-C) after {elapsed_s():.0f} s"


def node_timing(sup: Supervisor, t0_wall: float) -> dict:
    """What each node of this host wrote about its timing (its process's last incarnation's)."""
    timing = {}
    for p in sup.procs:
        for name in p.spec.nodes:
            path = stats_path(sup.log_dir, name, p.incarnation)
            if path.exists():
                timing[name] = {
                    "spawned_s": round(p.usage[-1].spawned - t0_wall, 2),
                    **relative_to(yaml.safe_load(path.read_text()), t0_wall),
                }
    return timing


def _restart_dead(sup: Supervisor, max_restarts: int, log) -> str:
    """Restart every node that died (the replay cannot be: it is the one that re-sends what
    a restarted stage missed); the failure message when a node cannot be restarted."""
    for p in sup.dead():
        hosting = f" (hosting {', '.join(p.spec.hosted)})" if p.spec.hosted else ""
        died = f"node '{p.spec.name}'{hosting} died (exit {p.popen.returncode})"
        if p.spec.name == topics.REPLAY_STAGE or len(p.exits) >= max_restarts:
            why = (
                "the replay cannot be restarted: nobody could re-send what the stages missed"
                if p.spec.name == topics.REPLAY_STAGE
                else f"it was restarted {len(p.exits)} times already"
            )
            return f"{died}; {why}; last log lines:\n{p.log_tail()}"
        sup.restart(p)
        log(f"warning: {died}; restarted it ({len(p.exits)} of at most {max_restarts}); it is sent what it missed")
    return ""
