import os
import subprocess
import sys
import time

from yowo_bringup.supervisor import Usage


def test_usage_of_a_live_process_and_of_a_gone_one():
    burn = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time\nx = bytearray(80 * 2**20)\nt = time.process_time()\n"
            "while time.process_time() - t < 0.5: pass\ntime.sleep(5)",
        ]
    )
    try:
        cpu = 0.0
        for _ in range(100):  # until it has burnt its half second
            cpu, rss = Usage.read(burn.pid)
            if cpu >= 0.5:
                break
            time.sleep(0.05)
        assert 0.45 < cpu < 5.0 and 80.0 < rss < 400.0, (cpu, rss)
        # Its 80 MB are its own; the interpreter's shared libraries count in part.
        assert 80.0 < Usage.pss_mb(burn.pid) <= rss, (Usage.pss_mb(burn.pid), rss)
    finally:
        burn.kill()
        burn.wait()
    assert Usage.read(burn.pid) is None and Usage.pss_mb(burn.pid) == 0.0
    me = Usage.read(os.getpid())
    assert me is not None and me[1] > 10.0


def test_node_processes_get_the_library_thread_count(tmp_path):
    from yowo_bringup.supervisor import NodeSpec, Supervisor, library_threads_env

    (tmp_path / "envdump.py").write_text(
        "import os, pathlib\npathlib.Path(os.environ['DUMP']).write_text("
        "' '.join(os.environ.get(k, '-') for k in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')))\n"
    )
    base = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    base.update(PYTHONPATH=str(tmp_path), DUMP=str(tmp_path / "dump"))
    for threads, expected in ((1, "1 1 1"), (0, "- - -")):
        sup = Supervisor(tmp_path / f"logs{threads}", library_threads_env(base, threads))
        proc = sup.start(NodeSpec(name="dump", module="envdump"))
        assert proc.popen.wait(timeout=60) == 0, proc.log_tail()
        assert (tmp_path / "dump").read_text() == expected
