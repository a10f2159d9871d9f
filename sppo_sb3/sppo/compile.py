"""``torch.compile`` for the hot paths, with the eager function as reference and fallback.

At the sizes SPPO runs on a CPU most of an eager plan or update is framework overhead: hundreds of small kernels
launched one by one from Python. Compiled, each becomes one graph: Inductor's fused C++ kernels on the CPU; CUDA graphs
(``mode="reduce-overhead"``) on CUDA, as TD-MPC2 does. On the CPU the kernels are called from Inductor's C++
wrapper rather than from Python. Shapes are static (``dynamic=False``): every distinct shape
(planning horizon, number of envs) is compiled once and cached.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Generic, Literal, ParamSpec, TypeVar

import torch as th
from torch._dynamo.utils import counters

CompileMode = bool | Literal["auto"]
RECOMPILE_LIMIT = 64
"""Graphs kept per function: one per planning horizon of the schedule and per number of envs planned for (training's
and each evaluation VecEnv's); PyTorch's default of 8 would send a long run with evaluation back to eager."""
P = ParamSpec("P")
R = TypeVar("R")


def check_compile_mode(compile: CompileMode) -> None:
    """Reject anything but ``True``, ``False`` and ``"auto"`` with a message that says what is accepted."""
    if compile not in (True, False, "auto") or not isinstance(compile, bool | str):
        raise ValueError(f"compile must be True, False or 'auto', got {compile!r}.")


def should_compile(compile: CompileMode, device: th.device) -> bool:
    """Resolve ``compile``: ``"auto"`` compiles on CPU and CUDA devices, where ``scripts/bench_training.py`` measures
    the compiled update and planner faster than eager once compiled.

    PyTorch's own switch, the environment variable ``TORCH_COMPILE_DISABLE=1``, turns compilation off everywhere.
    """
    check_compile_mode(compile)
    if th._dynamo.config.disable:
        return False
    return device.type in ("cpu", "cuda") if compile == "auto" else bool(compile)


class CompiledFunction(Generic[P, R]):
    """``fn`` compiled with ``torch.compile``, or ``fn`` itself when compilation is off or fails.

    A failure to compile (no C++ compiler, an unsupported operator, a PyTorch bug) is reported with one warning and
    the eager function is used from then on: the results are the same, only slower.

    :param fn: the function; the reference implementation.
    :param enabled: compile it (else run it eagerly).
    :param device: the device it runs on: CUDA uses CUDA graphs (``mode="reduce-overhead"``).
    :param name: what to call it in the warning.

    ``compilations`` and ``compile_seconds`` count the calls that compiled a new graph and the wall time they took.
    """

    def __init__(self, fn: Callable[P, R], enabled: bool, device: th.device, name: str) -> None:
        self.fn, self.name = fn, name
        self.compilations, self.compile_seconds = 0, 0.0
        self._compiled: Callable[P, R] | None = None
        if enabled and device.type == "cuda":
            self._compiled = th.compile(fn, mode="reduce-overhead", dynamic=False)
        elif enabled:  # C++ wrapper: the graph's kernels are called from C++, not one by one from Python
            self._compiled = th.compile(fn, dynamic=False, options={"cpp_wrapper": True})

    @property
    def compiled(self) -> bool:
        """Whether calls run the compiled graph (False after a failed compilation)."""
        return self._compiled is not None

    def __call__(self, *args: P.args, **kwargs: P.kwargs) -> R:
        if self._compiled is not None:
            try:
                graphs, start = counters["stats"]["unique_graphs"], time.perf_counter()
                # autograd.grad inside the graph; a graph per horizon and n_envs
                with th._dynamo.config.patch(trace_autograd_ops=True, recompile_limit=RECOMPILE_LIMIT):
                    result = self._compiled(*args, **kwargs)
                if counters["stats"]["unique_graphs"] != graphs:
                    self.compilations += 1
                    self.compile_seconds += time.perf_counter() - start
                return result
            except Exception as error:  # any compiler failure falls back to the reference
                warnings.warn(
                    f"torch.compile failed on SPPO's {self.name} ({type(error).__name__}: {error}); running it eagerly "
                    "from now on (same results, slower). Pass compile=False to skip compiling.",
                    RuntimeWarning,
                    stacklevel=2,
                )
                self._compiled = None
        return self.fn(*args, **kwargs)
