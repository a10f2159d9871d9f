"""The ``## Parameters`` tables of ``docs/modules/*.md`` follow the algorithms' docstrings (``scripts/parameter_tables.py``,
a tool of the repository, not of the installed package: imported here from its path).

Every algorithm of :data:`sppo_sb3.algorithms.ALGORITHMS` is covered, a future one included: its page must exist and
hold the generated table between the markers, and every argument of its constructor needs a ``:param:`` entry.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from sppo_sb3.algorithms import ALGORITHMS

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "parameter_tables.py"


def _load_script(path: Path) -> ModuleType:
    """Import the script at ``path`` as a module (``scripts/`` is no package)."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None, f"cannot import {path}"
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module
    spec.loader.exec_module(module)
    return module


docs_tables = _load_script(SCRIPT)


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_every_constructor_argument_has_a_param_entry(name: str) -> None:
    cls = ALGORITHMS[name].load_class()
    missing = docs_tables.missing_params(cls)
    assert not missing, f"{cls.__name__}'s class docstring has no :param: entry for {', '.join(missing)}"
    unknown = docs_tables.unknown_params(cls)
    assert not unknown, f"{cls.__name__}'s class docstring documents {', '.join(unknown)}, not arguments of __init__"


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_committed_parameters_table_is_the_generated_one(name: str) -> None:
    cls = ALGORITHMS[name].load_class()
    path = docs_tables.page_path(name)
    committed = docs_tables.committed_block(docs_tables.read_page(path), path)
    assert committed == docs_tables.generated_block(cls), (
        f"{path.relative_to(path.parents[2])}: the Parameters table differs from {cls.__name__}'s docstring; "
        f"regenerate it with `{docs_tables.REGENERATE}`"
    )


def test_sphinx_markup_becomes_markdown() -> None:
    text = (
        ":class:`~sppo_sb3.common.cost_policy.CostActorCriticPolicy`, :func:`x`, :py:meth:`a.b`, "
        ":attr:`the rule <sppo_sb3.SPPO.shield_rule>`, ``None``, a|b"
    )
    assert docs_tables.sphinx_to_markdown(text) == "`CostActorCriticPolicy`, `x`, `a.b`, `the rule`, `None`, a|b"


def test_table_comes_from_the_signature_and_the_docstring() -> None:
    class Algo:
        """Prose that is not a parameter.

        :param policy: the policy (``"MlpPolicy"``) or
            a :class:`~pkg.Policy` class.
        :param rate: ``a | b``.
        :param _init_setup_model: build the networks now.

        Closing prose.
        """

        def __init__(self, policy: str, rate: float = 1e-3, _init_setup_model: bool = True):
            pass

    assert docs_tables.render_table(Algo) == "\n".join(
        [
            "| argument | default | meaning |",
            "|---|---|---|",
            '| `policy` | required | the policy (`"MlpPolicy"`) or a `Policy` class. |',
            r"| `rate` | `0.001` | `a \| b`. |",
        ]
    )

    class Undocumented(Algo):
        """:param policy: the policy."""

    assert docs_tables.missing_params(Undocumented) == ["rate", "_init_setup_model"]
    with pytest.raises(ValueError, match="no :param: entry for rate, _init_setup_model"):
        docs_tables.render_table(Undocumented)


def test_write_rewrites_only_between_the_markers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--write`` regenerates a stale table and keeps the prose around it; the check then passes."""
    expected = {}
    for name, cls in docs_tables.algorithm_classes().items():
        source = docs_tables.page_path(name).read_text()
        expected[name] = docs_tables.replace_block(source, docs_tables.generated_block(cls))
        (tmp_path / f"{name}.md").write_text(source.replace("| `env` | required |", "| `env` | hand-edited |", 1))
    assert docs_tables.main(["--docs-dir", str(tmp_path)]) == 1
    assert f"{tmp_path / 'pdo.md'}: the Parameters table differs" in capsys.readouterr().out
    assert docs_tables.main(["--docs-dir", str(tmp_path), "--write"]) == 0
    for name, text in expected.items():
        assert (tmp_path / f"{name}.md").read_text() == text
    assert docs_tables.main(["--docs-dir", str(tmp_path)]) == 0
    (tmp_path / "pdo.md").write_text("## Parameters\n\n| argument | default | meaning |\n")
    assert docs_tables.main(["--docs-dir", str(tmp_path)]) == 1
    assert "pdo.md: needs one" in capsys.readouterr().err
    (tmp_path / "pdo.md").unlink()
    assert docs_tables.main(["--docs-dir", str(tmp_path)]) == 1
    assert "pdo.md: no such page" in capsys.readouterr().err


def test_script_checks_the_repository_pages() -> None:
    """``python scripts/parameter_tables.py`` checks this checkout's pages against this checkout's package."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    result = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stdout + result.stderr
