"""A forked child's results come back in order, each once; what it does not deliver (it raised, it
was killed) is None, for the caller to make; no fork without the worker's allowance."""

import os
import signal
import time

import numpy as np
import psutil
import pytest

from sssbake.pipeline.bake import beside
from sssbake.pipeline.bake.beside import Beside, allow_fork

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or len(os.sched_getaffinity(0)) < 2,
                                reason="needs fork and two CPUs")


@pytest.fixture(autouse=True)
def no_allowance_left():
    yield
    beside._fork_allowed = False  # a test's unused allowance must not reach the next test


def test_no_fork_without_the_allowance():
    assert Beside.start(lambda: iter([("a", 1)])) is None


def test_results_in_order_each_taken_once_and_one_fork_per_allowance():
    allow_fork()

    def work():
        yield "numbers", np.arange(5.0)
        yield ("pid", 0), os.getpid()

    with Beside.start(work) as child:
        assert Beside.start(work) is None  # the allowance is spent
        np.testing.assert_array_equal(child.take("numbers"), np.arange(5.0))
        assert child.take(("pid", 0)) == child.pid != os.getpid()
        assert child.take("numbers") is None  # taken already, and the child has ended
        assert child.take("never sent") is None


def test_what_the_child_did_not_make_is_none():
    allow_fork()

    def work():
        yield "first", 1
        raise RuntimeError("made in the parent instead")

    with Beside.start(work) as child:
        assert child.take("first") == 1
        assert child.take("second") is None


def test_a_killed_child_delivers_nothing_more():
    allow_fork()

    def work():
        yield "first", 1
        os.kill(os.getpid(), signal.SIGKILL)
        yield "second", 2

    with Beside.start(work) as child:
        assert child.take("second") is None
        assert child.take("first") == 1  # sent before it died


def test_close_ends_a_child_still_working():
    allow_fork()

    def work():
        yield "started", True
        time.sleep(3600)
        yield "never", None

    child = Beside.start(work)
    assert child.take("started") is True
    child.close()
    assert not psutil.pid_exists(child.pid)  # killed and reaped, not a zombie
