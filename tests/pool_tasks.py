"""Tasks for the process-pool tests, in a module that imports nothing heavy: a spawned worker
imports the module of the function it is sent, and these tests only need its pid (importing
test_campaigns, with Drake, matplotlib and the whole package, cost each worker seconds)."""

import os
import time


def worker_pid(_):
    """The pid of the process that ran the task."""
    return os.getpid()


def pid_after(seconds):
    """The pid of the process that ran the task, after sleeping `seconds`."""
    time.sleep(seconds)
    return os.getpid()
