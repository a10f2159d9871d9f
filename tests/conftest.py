"""Test-session settings: one compute thread per pytest-xdist worker, and eager (uncompiled) SPPO by default.

With ``pytest -n 2`` on a 2-core machine, torch's default of one thread per core would run four busy threads on two
cores (and the subprocesses of the CLI tests more); oversubscribed BLAS threads spin and slow everything down.

``TORCH_COMPILE_DISABLE=1`` (PyTorch's own switch, inherited by the CLI tests' subprocesses) makes SPPO's
``compile="auto"`` run the eager reference: compiling each test's network shapes would cost more than the tests.
``tests/sppo/test_compile.py`` turns compilation back on to test the compiled paths against the eager ones. The examples
are imported once, by ``load_example``.
"""

import os

os.environ["TORCH_COMPILE_DISABLE"] = "1"

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest
import torch  # after the switch above, which torch reads on import

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"  # inherited by the CLI tests' subprocesses
    torch.set_num_threads(1)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="session")
def load_example() -> Callable[[str], ModuleType]:
    """Import ``examples/<name>.py`` once per session (it registers its env and rule on import)."""

    def load(name: str) -> ModuleType:
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
            assert spec is not None and spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        return sys.modules[name]

    return load
