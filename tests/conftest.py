"""Test-session settings: one compute thread per pytest-xdist worker, and eager (uncompiled) SPPO by default.

With ``pytest -n 2`` on a 2-core machine, torch's default of one thread per core would run four busy threads on two
cores (and the subprocesses of the CLI tests more); oversubscribed BLAS threads spin and slow everything down.

``TORCH_COMPILE_DISABLE=1`` (PyTorch's own switch, inherited by the CLI tests' subprocesses) makes SPPO's
``compile="auto"`` run the eager reference: compiling each test's network shapes would cost more than the tests.
``tests/test_compile.py`` turns compilation back on to test the compiled paths against the eager ones.
"""

import os

os.environ["TORCH_COMPILE_DISABLE"] = "1"

import torch  # after the switch above, which torch reads on import

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"  # inherited by the CLI tests' subprocesses
    torch.set_num_threads(1)
