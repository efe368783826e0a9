from yowo_bringup.config import load_config
from yowo_bringup.run import plan_live


def test_downstream_stages_can_run_at_a_lower_priority(tmp_path):
    plan = plan_live(["a", "b"], tmp_path, config=load_config(None, ["supervisor.downstream_niceness=5"]))
    nice = {n.name: n.niceness for n in plan.nodes}
    assert nice == {"keypoint_tracker_a": 0, "keypoint_tracker_b": 0, "group_sfm": 5, "ego_mapper": 0, "fusion": 5}
    assert all(n.niceness == 0 for n in plan_live(["a", "b"], tmp_path).nodes)     # the default
