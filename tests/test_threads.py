"""A command computes on the cores other processes leave idle (runout.threads)."""

import os
import subprocess
import sys

from runout.threads import threads_for


def test_threads_leave_out_the_cores_other_processes_hold():
    assert threads_for(cores=2, load=0.0, running=1) == 2  # idle machine: every core
    assert threads_for(cores=2, load=1.0, running=2) == 1  # one training process beside us
    assert threads_for(cores=2, load=2.3, running=3) == 1  # both cores busy: still one thread
    assert threads_for(cores=16, load=4.2, running=5) == 12


def test_a_load_that_has_ended_or_a_burst_just_begun_does_not_count():
    assert threads_for(cores=2, load=1.0, running=1) == 2  # the load average still remembers a finished run
    assert threads_for(cores=2, load=0.1, running=3) == 2  # two processes runnable this instant, no load


def test_the_users_choice_of_threads_is_kept():
    env = {**os.environ, "OMP_NUM_THREADS": "3"}
    out = subprocess.run([sys.executable, "-c", "from runout.threads import choose_threads; import os; "
                          "print(choose_threads(), os.environ['OMP_NUM_THREADS'])"],
                         env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["None", "3"]


def test_a_fresh_command_on_a_busy_machine_stays_silent_and_sets_its_threads():
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    code = ("import runout.threads as t; t.machine = lambda: (2, 1.0, 2); "
            "print(t.choose_threads(), __import__('os').environ['OMP_NUM_THREADS'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"] and out.stderr == ""
