"""Test-session settings: one compute thread per pytest-xdist worker.

With ``pytest -n 2`` on a 2-core machine, torch's default of one thread per core would run four busy threads on two
cores (and the subprocesses of the CLI tests more); oversubscribed BLAS threads spin and slow everything down.
"""

import os

import torch

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"  # inherited by the CLI tests' subprocesses
    torch.set_num_threads(1)
