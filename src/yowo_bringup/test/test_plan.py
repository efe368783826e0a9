from yowo_bringup.config import load_config
from yowo_bringup.run import plan_live


def test_downstream_stages_can_run_at_a_lower_priority(tmp_path):
    plan = plan_live(["a", "b"], tmp_path, config=load_config(None, ["supervisor.downstream_niceness=5"]))
    nice = {n.name: n.niceness for n in plan.nodes}
    assert nice == {"keypoint_tracker_a": 0, "keypoint_tracker_b": 0, "group_sfm": 5, "ego_mapper": 0, "fusion": 5}
    assert all(n.niceness == 0 for n in plan_live(["a", "b"], tmp_path).nodes)  # the default


def test_many_trackers_share_a_few_processes(tmp_path):
    from yowo_common.ros.context import hosted_node_names

    cams = [f"c{i}" for i in range(10)]
    plan = plan_live(cams, tmp_path, config=load_config(None, ["supervisor.tracker_processes=4"]))
    procs = plan.local_processes
    hosts = [p for p in procs if p.hosted]
    assert [p.name for p in hosts] == [f"keypoint_trackers_{i}" for i in range(4)]
    # Every tracker in exactly one process, 2-3 each; the other stages alone, in their order.
    assert sorted(n for p in hosts for n in p.hosted) == sorted(f"keypoint_tracker_{c}" for c in cams)
    assert [len(p.hosted) for p in hosts] == [3, 3, 2, 2]
    assert [p.name for p in procs if not p.hosted] == ["group_sfm", "ego_mapper", "fusion"]
    assert procs.index(hosts[0]) == 0
    # The hosted nodes keep their own names and parameters (the params file is per node).
    assert {n.name for n in plan.nodes} >= {f"keypoint_tracker_{c}" for c in cams}
    # Few cameras, or 0: one process per tracker, as the nodes are.
    few = plan_live(cams[:3], tmp_path)
    assert few.local_processes == few.local_nodes
    off = plan_live(cams, tmp_path, config=load_config(None, ["supervisor.tracker_processes=0"]))
    assert off.local_processes == off.local_nodes
    # What a hosting process reads from its command line.
    assert hosted_node_names(["x", "--nodes", "a,b", "--ros-args", "-p", "q:=1"]) == ["a", "b"]
    assert hosted_node_names(["x", "--ros-args", "--nodes", "a"]) == []


def test_a_run_id_that_looks_like_a_number_reaches_the_nodes_as_a_string(tmp_path):
    """rcl reads the parameter file: an unquoted 138531451e07 (a hex run id) would be a
    double, and a node declaring run_id as a string would refuse it."""
    import rclpy
    from rclpy.node import Node

    from yowo_bringup.supervisor import write_params_file

    plan = plan_live(["a", "b"], tmp_path)
    for spec in plan.nodes:
        spec.parameters["run_id"] = "138531451e07"
    path = tmp_path / "params.yaml"
    write_params_file(plan.nodes, path)
    name = plan.nodes[0].name
    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context)
    try:
        node = Node(name, context=context)
        assert node.declare_parameter("run_id", "").value == "138531451e07"
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_cmc_only_run_hands_on_everyone_in_view_only_when_asked(tmp_path):
    from yowo_bringup.run import CMC
    from yowo_common import topics

    on = load_config(None, ["cmc.people.others_as_evidence=true"])
    plan = plan_live(["a", "b"], tmp_path, mode=CMC, source="pose", config=on)
    params = {n.name: n.parameters for n in plan.nodes}
    assert params["keypoint_tracker_a"]["publish_people"] is True
    assert params["group_sfm"]["people_cameras"] == ["a", "b"]
    assert topics.PEOPLE in plan.outputs
    # Off by default, and never in a full run (the walker is the ego camera's link there).
    for plan in (
        plan_live(["a", "b"], tmp_path, mode=CMC, source="pose"),
        plan_live(["a", "b"], tmp_path, source="pose", config=on),
    ):
        params = {n.name: n.parameters for n in plan.nodes}
        assert "publish_people" not in params["keypoint_tracker_a"] and "people_cameras" not in params["group_sfm"]
        assert topics.PEOPLE not in plan.outputs
