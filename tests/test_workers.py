"""Pool workers end with the process that started them (hybridpose.workers): a parent killed outright
(SIGKILL: no handler runs) leaves no worker behind; without the watch one stays."""
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PARENT = textwrap.dedent("""
    import multiprocessing, os, sys, time
    from concurrent.futures import ProcessPoolExecutor
    from hybridpose.workers import spawn_executor

    def worker_pid(_):
        return os.getpid()

    if __name__ == "__main__":
        if sys.argv[1] == "watched":
            pool = spawn_executor(1)
        else:
            pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        print(pool.submit(worker_pid, 0).result(), flush=True)
        time.sleep(120)
""")


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and has not exited (a zombie awaiting its reaper has)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("watched", [True, False])
def test_a_pool_worker_ends_when_its_parent_is_killed(tmp_path, watched):
    from hybridpose.workers import PARENT_POLL_S

    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    parent = subprocess.Popen([sys.executable, str(script), "watched" if watched else "plain"], stdout=subprocess.PIPE,
                              text=True)
    worker = int(parent.stdout.readline())
    try:
        assert _running(worker)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 4 * PARENT_POLL_S
        while _running(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _running(worker) != watched
    finally:
        if _running(worker):
            os.kill(worker, signal.SIGKILL)
