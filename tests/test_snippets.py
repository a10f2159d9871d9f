"""Every ```python block of the README and of the documentation's guide and algorithm pages runs.

Each block runs on its own, in a fresh namespace, in a temporary folder, with the repository root importable (the
pages' examples import ``examples.*`` from there), and with its training budgets shrunk so that the whole file stays
fast: ``.learn(N)`` / ``total_timesteps=N`` to :data:`LEARN_STEPS`, ``learning_starts`` and ``n_steps`` to a few
dozen (also an on-policy algorithm's default rollout of 2048 steps), ``range(N)`` loops to :data:`LOOP_STEPS`,
``n_eval_episodes`` to 1, and the registered tasks' episodes to :data:`EPISODE_STEPS`; torch runs one thread. What a
block registers (gymnasium ids, shielding rules) is undone after it, so no block and no other test sees another's
registrations.

A block that cannot run here opts out with a marker comment that says why, on a line of its own::

    # snippet: skip (needs the dmc extra)

A marker without a reason fails.
"""

from __future__ import annotations

import copy
import dataclasses
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

ROOT = Path(__file__).resolve().parents[1]
PAGES = [
    ROOT / "README.md",
    *sorted((ROOT / "docs" / "guide").glob("*.md")),
    *sorted((ROOT / "docs" / "modules").glob("*.md")),
]
LEARN_STEPS = 64
"""Env steps of every ``learn`` call: past the shrunk warm-up, so that the algorithms' updates run too."""
LEARNING_STARTS = 32
ROLLOUT_STEPS = 32
LOOP_STEPS = 20
EPISODE_STEPS = 50
"""Time limit of every registered task while a block runs (``evaluate_policy`` plays whole episodes)."""

FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```", re.MULTILINE | re.DOTALL)
SKIP = re.compile(r"^\s*#\s*snippet:\s*skip\b(.*)$", re.MULTILINE)
SHRINK = [
    (re.compile(r"\.learn\(\s*(total_timesteps\s*=\s*)?[\d_]+"), rf".learn(\g<1>{LEARN_STEPS}"),
    (re.compile(r"\blearning_starts\s*=\s*[\d_]+"), f"learning_starts={LEARNING_STARTS}"),
    (re.compile(r"\bn_steps\s*=\s*[\d_]+"), f"n_steps={ROLLOUT_STEPS}"),
    (re.compile(r"\brange\(\s*[\d_]+\s*\)"), f"range({LOOP_STEPS})"),
    (re.compile(r"\bn_eval_episodes\s*=\s*\d+"), "n_eval_episodes=1"),
]


@dataclass(frozen=True)
class Snippet:
    page: Path
    line: int
    code: str

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    @property
    def skip_reason(self) -> str | None:
        """The marker's reason (``""`` where the marker gives none), or ``None`` without a marker."""
        match = SKIP.search(self.code)
        return None if match is None else match.group(1).strip(" \t()—-:").strip()


def snippets(page: Path) -> list[Snippet]:
    text = page.read_text(encoding="utf-8")
    return [Snippet(page, text.count("\n", 0, match.start()) + 1, match.group(1)) for match in FENCE.finditer(text)]


def shrink(code: str) -> str:
    for pattern, replacement in SHRINK:
        code = pattern.sub(replacement, code)
    return code


ALL = [snippet for page in PAGES for snippet in snippets(page)]


def test_pages_have_snippets() -> None:
    """The collection finds the blocks (a renamed page or a changed fence would silently test nothing)."""
    assert any(snippet.page.name == "README.md" for snippet in ALL)
    assert len(ALL) >= 10, [snippet.name for snippet in ALL]


def test_shrink_rewrites_the_budgets() -> None:
    code = "m.learn(100_000, progress_bar=True)\nm.learn(total_timesteps=20_000)\nX(learning_starts=400, n_steps=2048)\n"
    code += "for _ in range(500):\n"
    assert shrink(code) == (
        f"m.learn({LEARN_STEPS}, progress_bar=True)\nm.learn(total_timesteps={LEARN_STEPS})\n"
        f"X(learning_starts={LEARNING_STARTS}, n_steps={ROLLOUT_STEPS})\nfor _ in range({LOOP_STEPS}):\n"
    )


def test_skip_marker_needs_a_reason() -> None:
    page = ROOT / "README.md"
    assert Snippet(page, 1, "x = 1\n").skip_reason is None
    assert Snippet(page, 1, "# snippet: skip (needs the dmc extra)\nx = 1\n").skip_reason == "needs the dmc extra"
    assert Snippet(page, 1, "# snippet: skip\nx = 1\n").skip_reason == ""
    assert Snippet(page, 1, "# snippet: skip ()\nx = 1\n").skip_reason == ""


@pytest.fixture
def isolated_registries(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[None]:
    """Run in a temporary folder with the repository importable; undo the block's registrations afterwards."""
    import gymnasium
    import torch

    from sppo_sb3.shield import RULE_ENV_PARAMETERS, SHIELDING_RULES

    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    init = OnPolicyAlgorithm.__init__

    def short_rollouts(self: OnPolicyAlgorithm, *args: Any, **kwargs: Any) -> None:
        kwargs["n_steps"] = min(kwargs["n_steps"], ROLLOUT_STEPS)  # SB3's on-policy algorithms pass it by keyword
        init(self, *args, **kwargs)

    monkeypatch.setattr(OnPolicyAlgorithm, "__init__", short_rollouts)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # on a busy machine, idle-spinning intra-op threads slow SPPO's small updates tenfold
    saved_rules, saved_parameters = dict(SHIELDING_RULES), dict(RULE_ENV_PARAMETERS)
    registry = gymnasium.envs.registration.registry
    saved_envs = copy.copy(registry)
    for env_id, spec in saved_envs.items():
        if spec.max_episode_steps is not None and spec.max_episode_steps > EPISODE_STEPS:
            registry[env_id] = dataclasses.replace(spec, max_episode_steps=EPISODE_STEPS)
    saved_modules = set(sys.modules)
    yield
    torch.set_num_threads(threads)
    SHIELDING_RULES.clear()
    SHIELDING_RULES.update(saved_rules)
    RULE_ENV_PARAMETERS.clear()
    RULE_ENV_PARAMETERS.update(saved_parameters)
    registry.clear()
    registry.update(saved_envs)
    for name in set(sys.modules) - saved_modules:
        if name == "examples" or name.startswith("examples."):
            del sys.modules[name]


@pytest.mark.parametrize("snippet", ALL, ids=lambda snippet: snippet.name)
def test_snippet_runs(snippet: Snippet, isolated_registries: None) -> None:
    reason = snippet.skip_reason
    if reason is not None:
        assert reason, f"{snippet.name}: a '# snippet: skip' marker needs a reason, e.g. '# snippet: skip (needs a GPU)'"
        pytest.skip(reason)
    code = compile(shrink(snippet.code), snippet.name, "exec")
    exec(code, {"__name__": "__snippet__"})
