"""The CLI explains its safety outputs: ``sppo-train -h`` says what they mean, the summary at the end of training carries
a line of legend, and ``safety_summary.json`` has exactly the fields that ``docs/guide/cli.md`` documents (the test reads
them from the page's table, so the page cannot drift from the file).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from tiny_hyperparams import TINY_ZOO

from sppo_sb3 import train, zoo
from sppo_sb3.zoo.experiment import SAFETY_LEGEND

CLI_PAGE = Path(__file__).resolve().parents[2] / "docs" / "guide" / "cli.md"
FIELDS_HEADING = "### The fields of `safety_summary.json`"
ENV = "SafePointCircle-v0"
#: what the help must explain (case-insensitive)
HELP_TERMS = ("safety rate", "violations", "interventions", "eval_unshielded", "safety_summary.json")


def documented_fields(page: str) -> list[str]:
    """The first-column names of the table under :data:`FIELDS_HEADING` (dotted paths into the nested json).

    :param page: the text of ``docs/guide/cli.md``.
    """
    assert FIELDS_HEADING in page, f"{CLI_PAGE} has no {FIELDS_HEADING!r} section"
    section = page.split(FIELDS_HEADING, 1)[1]
    section = re.split(r"^#{1,6} ", section, maxsplit=1, flags=re.MULTILINE)[0]  # up to the next heading
    rows = [line for line in section.splitlines() if line.startswith("|")]
    fields = [m.group(1) for line in rows[2:] if (m := re.match(r"\|\s*`([^`]+)`\s*\|", line))]  # past header, rule
    assert len(fields) == len(rows) - 2, f"every row of the table in {CLI_PAGE} names one field in backquotes"
    return fields


def leaf_paths(value: Any, prefix: str = "") -> list[str]:
    """The dotted paths of the non-dict values of a nested dict (``{"a": {"b": 1}}`` gives ``["a.b"]``)."""
    if not isinstance(value, dict):
        return [prefix]
    return [path for key, child in value.items() for path in leaf_paths(child, f"{prefix}.{key}" if prefix else key)]


def test_the_fields_table_is_read_as_written() -> None:
    """The parser itself can fail: it takes each row's field, stops at the next heading, and rejects a row without one."""
    page = f"intro\n{FIELDS_HEADING}\n\n| field | meaning |\n|---|---|\n| `a` | x |\n| `b.c` | y |\n\n## Next\n| `z` | no |\n"
    assert documented_fields(page) == ["a", "b.c"]
    with pytest.raises(AssertionError, match="names one field"):
        documented_fields(page.replace("| `b.c` |", "| b.c |"))
    assert leaf_paths({"n": 1, "d": {"e": {"x": 1.0, "y": 2.0}}}) == ["n", "d.e.x", "d.e.y"]


@pytest.mark.parametrize("command", ["console script", "module"])
def test_help_explains_the_safety_outputs(command: str) -> None:
    script = Path(sys.executable).parent / "sppo-train"
    if command == "console script" and not script.exists():
        pytest.skip(f"no console script {script} (the package is not installed in this interpreter's environment)")
    cmd = [str(script), "-h"] if command == "console script" else [sys.executable, "-m", "sppo_sb3.train", "-h"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    text = result.stdout.lower()
    missing = [term for term in HELP_TERMS if term not in text]
    assert not missing, f"`{' '.join(cmd)}` does not explain {missing}"
    assert "--deployment-episodes" in text and "--violation-budget" in text and "--algo" in text  # ours and rl-zoo3's


def test_summary_has_exactly_the_documented_fields(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run with every output on (safety metrics, periodic evaluations, deployments) saves the documented fields, all
    of them and no others, and prints the legend under its summary."""
    fields = documented_fields(CLI_PAGE.read_text())
    assert len(fields) == len(set(fields)), f"a field is documented twice in {CLI_PAGE}"
    # no -conf: the package's own hyperparams/pdo.yml, made tiny
    argv = ["--algo", "pdo", "--env", ENV, "-n", "128", "-f", str(tmp_path), "--seed", "0", "--num-threads", "1"]
    argv += ["--device", "cpu", "--eval-freq", "64", "--eval-episodes", "2", "--deployment-episodes", "2"]
    argv += ["--env-kwargs", "max_episode_steps:50", "--hyperparams", *TINY_ZOO["pdo"]]
    try:
        train.main(argv)
    finally:
        zoo.install()  # the deployment episodes back to their default for the other tests of the process
    out = capsys.readouterr().out
    assert f"Loading hyperparameters from: {zoo.default_config('pdo', ENV)}" in out
    assert SAFETY_LEGEND in out

    summary = json.loads((tmp_path / "pdo" / f"{ENV}_1" / "safety_summary.json").read_text())
    saved = leaf_paths(summary)
    assert sorted(saved) == sorted(fields), (
        f"safety_summary.json and the table in {CLI_PAGE.name} differ: "
        f"undocumented {sorted(set(saved) - set(fields))}, documented but not saved {sorted(set(fields) - set(saved))}"
    )
