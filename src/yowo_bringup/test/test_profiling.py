import subprocess
import sys

from yowo_bringup.profiling import NodeProfiler, read_collapsed, summary_markdown, top_functions

BURN = """

def burn():
    s = 0
    for i in range(3 * 10**6):
        s += i
    return s


def idle():
    import time
    time.sleep(0.5)


for _ in range(8):
    burn()
idle()
"""


def test_py_spy_records_a_process_from_its_start_and_summarises_it(tmp_path):
    script = tmp_path / "yowo_burn.py"
    script.write_text(BURN)
    proc = subprocess.Popen([sys.executable, str(script)])
    profiler = NodeProfiler(proc.pid, tmp_path / "burner.txt", 100)  # attached while it starts
    proc.wait(120)
    profiler.wait(30)
    assert profiler.error == ""
    stacks = read_collapsed(tmp_path / "burner.txt")
    top = top_functions(stacks)
    own = dict(top["own"])
    burn = next(f for f in own if f.startswith("burn "))
    # The loop is where the time went; the sleep is idle (not sampled: sampled, its 0.5 s would be
    # ~15 % of the samples; on a loaded machine a sample or two land on the wake-up).
    assert own[burn] > 0.6 * top["samples"], top
    assert sum(n for f, n in own.items() if f.startswith("idle ")) < 0.05 * top["samples"], top
    text = summary_markdown(tmp_path, 100)
    assert "## burner: " in text and " s not idle" in text and "`burn (" in text


def test_collapsed_stacks_phases_and_project_functions(tmp_path):
    (tmp_path / "n.txt").write_text(
        "<module> (yowo_x/n.py:1);_find_and_load (<frozen importlib._bootstrap>:1) 3\n"
        "<module> (yowo_x/n.py:1);spin (rclpy/__init__.py:9);Executor._wait (rclpy/executors.py:5) 2\n"
        "<module> (yowo_x/n.py:1);spin (rclpy/__init__.py:9);cb (yowo_x/n.py:20);heavy (yowo_x/alg.py:7) 4\n"
        "<module> (yowo_x/n.py:1);spin (rclpy/__init__.py:9);cb (yowo_x/n.py:21);heavy (yowo_x/alg.py:8) 1\n"
    )
    top = top_functions(read_collapsed(tmp_path / "n.txt"))
    assert top["samples"] == 10
    assert dict(top["phases"]) == {"imports": 3, "rclpy (executor, wait sets)": 2, "callbacks and the rest": 5}
    # One entry per function (lines merged); module bodies are not project functions.
    assert top["own"][0] == ("heavy (yowo_x/alg.py)", 5)
    assert dict(top["cumulative"]) == {"heavy (yowo_x/alg.py)": 5, "cb (yowo_x/n.py)": 5}


def test_a_process_py_spy_cannot_record_is_said(tmp_path):
    sleeper = subprocess.Popen(["sleep", "30"])  # no Python interpreter in it
    try:
        profiler = NodeProfiler(sleeper.pid, tmp_path / "sleeper.txt", 50, give_up_s=1.0)
        profiler.wait(20)
        assert profiler.error.startswith(f"py-spy could not record pid {sleeper.pid}: "), profiler.error
    finally:
        sleeper.kill()
        sleeper.wait()
