"""A worker that asked to die with its parent does, and one that did not outlives it."""

import os
import subprocess
import sys
import time

import psutil
import pytest

# The middle process starts a sleeping grandchild (which may ask to die with its parent), prints its
# pid once it is ready and then waits to be killed.
MIDDLE = """
import subprocess, sys, time
code = ("from sssbake.pipeline.mesh.parent_death import die_with_parent\\n"
        + ("die_with_parent()\\n" if sys.argv[1] == "1" else "") + "print(flush=True); import time; time.sleep(60)")
child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
child.stdout.readline()  # it has called it
print(child.pid, flush=True)
time.sleep(60)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("asks", [True, False])
def test_a_grandchild_dies_with_its_killed_parent_only_when_it_asked(asks):
    middle = subprocess.Popen([sys.executable, "-c", MIDDLE, "1" if asks else "0"], stdout=subprocess.PIPE, text=True)
    grandchild = int(middle.stdout.readline())
    try:
        middle.kill()
        middle.wait()
        deadline = time.monotonic() + 5
        while psutil.pid_exists(grandchild) and psutil.Process(grandchild).status() != psutil.STATUS_ZOMBIE \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        alive = psutil.pid_exists(grandchild) and psutil.Process(grandchild).status() != psutil.STATUS_ZOMBIE
        assert alive is not asks
    finally:
        if psutil.pid_exists(grandchild):
            os.kill(grandchild, 9)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_child_whose_parent_died_before_it_asked_ends_at_once():
    # the parent named is not this process's: as if it had died while the child was importing
    code = "from sssbake.pipeline.mesh.parent_death import die_with_parent; die_with_parent(1); print('still here')"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == -9 and "still here" not in done.stdout
