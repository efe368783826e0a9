import os
import subprocess
import sys
import time

from yowo_bringup.supervisor import Usage


def test_usage_of_a_live_process_and_of_a_gone_one():
    burn = subprocess.Popen([sys.executable, "-c", "import time\nx = bytearray(80 * 2**20)\nt = time.process_time()\n"
                             "while time.process_time() - t < 0.5: pass\ntime.sleep(5)"])
    try:
        cpu = 0.0
        for _ in range(100):                # until it has burnt its half second
            cpu, rss = Usage.read(burn.pid)
            if cpu >= 0.5:
                break
            time.sleep(0.05)
        assert 0.45 < cpu < 5.0 and 80.0 < rss < 400.0, (cpu, rss)
    finally:
        burn.kill()
        burn.wait()
    assert Usage.read(burn.pid) is None
    me = Usage.read(os.getpid())
    assert me is not None and me[1] > 10.0
