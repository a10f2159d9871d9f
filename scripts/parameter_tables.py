"""The ``## Parameters`` tables of ``docs/modules/<algo>.md``, generated from each algorithm's docstring.

The class docstring is the single source: for every algorithm of :data:`sppo_sb3.algorithms.ALGORITHMS`, the table
``| argument | default | meaning |`` lists the arguments of ``__init__`` in signature order, with the default read
from :func:`inspect.signature` (``required`` where there is none) and the meaning from the class docstring's
``:param name: text`` entry, Sphinx markup turned into markdown (:func:`sphinx_to_markdown`). Left out are SB3's
private arguments (``_init_setup_model``), which still need the entry. In each page the table lies between
:data:`BEGIN` and :data:`END`; everything outside them is hand-written.

The script checks that each page's table matches the class docstring and signature, and exits with status 1 where
one does not (as ``tests/test_docs.py`` does); ``--write`` rewrites the stale tables in place::

    python scripts/parameter_tables.py           # check
    python scripts/parameter_tables.py --write   # regenerate after editing a docstring

A tool of the repository, not of the installed package: it reads and writes the checkout's ``docs/modules``. The
algorithm classes are imported only when a table is asked for.
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from sppo_sb3.algorithms import ALGORITHMS

#: the repository's ``docs/modules`` folder (this script lies in its ``scripts/``)
REPO_DOCS_DIR = Path(__file__).resolve().parents[1] / "docs" / "modules"
#: the command that regenerates the tables
REGENERATE = "python scripts/parameter_tables.py --write"
#: the line before each generated table
BEGIN = "<!-- parameters: generated from the docstring by scripts/parameter_tables.py; do not edit -->"
#: the line after each generated table
END = "<!-- /parameters -->"

_PARAM = re.compile(r":param\s+(\w+):\s*(.*)")
_ROLE = re.compile(r":(?:\w+:)?\w+:`(~?)([^`]+)`")
_TITLED_TARGET = re.compile(r"(.+?)\s*<[^>]+>")
_LITERAL = re.compile(r"``(.+?)``")


def sphinx_to_markdown(text: str) -> str:
    """Sphinx roles and literals as markdown code spans.

    ``:class:`~a.b.C``` gives ```C``` (the last component, as Sphinx shows it), ``:func:`a.b``` gives ```a.b```,
    ``:role:`title <target>``` gives ```title```, and a double-backquoted literal a single-backquoted one.
    """

    def role(match: re.Match[str]) -> str:
        tilde, target = match.groups()
        titled = _TITLED_TARGET.fullmatch(target)
        if titled is not None:
            return f"`{titled.group(1)}`"
        return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"

    return _LITERAL.sub(r"`\1`", _ROLE.sub(role, text))


def param_docs(cls: type) -> dict[str, str]:
    """The ``:param name: text`` entries of ``cls``'s own docstring, continuation lines joined, in markdown.

    :param cls: the algorithm class (its docstring, not an inherited one: SB3's would describe other arguments).
    """
    entries: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in inspect.cleandoc(cls.__doc__ or "").splitlines():
        param = _PARAM.match(line)
        if param is not None:
            current = entries.setdefault(param.group(1), [])
            current.append(param.group(2).strip())
        elif current is not None and line[:1].isspace() and line.strip():  # an indented continuation line
            current.append(line.strip())
        else:  # a blank line, another field or unindented prose ends the entry
            current = None
    return {name: sphinx_to_markdown(" ".join(parts)) for name, parts in entries.items()}


def constructor_parameters(cls: type) -> list[inspect.Parameter]:
    """The arguments of ``cls.__init__`` (``self`` left out), private ones included, in signature order."""
    return list(inspect.signature(cls).parameters.values())  # a class's signature is its __init__'s without self


def missing_params(cls: type) -> list[str]:
    """The constructor arguments, private ones included, that the class docstring has no ``:param:`` entry for."""
    documented = param_docs(cls)
    return [p.name for p in constructor_parameters(cls) if p.name not in documented]


def unknown_params(cls: type) -> list[str]:
    """The class docstring's ``:param:`` entries that name no constructor argument (left over from a removed one)."""
    arguments = {p.name for p in constructor_parameters(cls)}
    return [name for name in param_docs(cls) if name not in arguments]


def _cell(text: str) -> str:
    return text.replace("|", r"\|")


def listed(name: str) -> bool:
    """Whether the argument ``name`` has a row: every argument but SB3's private ones."""
    return not name.startswith("_")


def render_table(cls: type) -> str:
    """The markdown table of ``cls``'s constructor arguments, as :func:`listed` selects them (no trailing newline).

    :raises ValueError: where an argument has no ``:param:`` entry.
    """
    docs = param_docs(cls)
    missing = missing_params(cls)
    if missing:
        raise ValueError(f"{cls.__name__}'s docstring has no :param: entry for {', '.join(missing)}")
    rows = ["| argument | default | meaning |", "|---|---|---|"]
    for p in constructor_parameters(cls):
        if not listed(p.name):
            continue
        default = "required" if p.default is inspect.Parameter.empty else f"`{p.default!r}`"
        rows.append(f"| `{p.name}` | {_cell(default)} | {_cell(docs[p.name])} |")
    return "\n".join(rows)


def generated_block(cls: type) -> str:
    """The table between its markers, as it stands in the page."""
    return f"{BEGIN}\n\n{render_table(cls)}\n\n{END}"


def _block_span(page: str, path: Path | str) -> tuple[int, int]:
    start, end = page.find(BEGIN), page.find(END)
    if start < 0 or end < start or page.count(BEGIN) != 1 or page.count(END) != 1:
        raise ValueError(f"{path}: needs one {BEGIN!r} line and, after it, one {END!r} line around its Parameters table")
    return start, end + len(END)


def committed_block(page: str, path: Path | str = "page") -> str:
    """The table between its markers, as the page has it (markers included)."""
    start, end = _block_span(page, path)
    return page[start:end]


def replace_block(page: str, block: str, path: Path | str = "page") -> str:
    """``page`` with the text between (and including) the markers replaced by ``block``."""
    start, end = _block_span(page, path)
    return page[:start] + block + page[end:]


def page_path(name: str, docs_dir: Path = REPO_DOCS_DIR) -> Path:
    """The documentation page of the algorithm ``name`` (a key of :data:`~sppo_sb3.algorithms.ALGORITHMS`)."""
    return docs_dir / f"{name}.md"


def read_page(path: Path) -> str:
    """The text of the page ``path``.

    :raises ValueError: where there is none (an algorithm added to the list without its page).
    """
    if not path.is_file():
        raise ValueError(f"{path}: no such page; every algorithm needs one, with its table between {BEGIN!r} and {END!r}")
    return path.read_text()


def algorithm_classes() -> dict[str, type]:
    """The package's algorithm classes by name, from :data:`~sppo_sb3.algorithms.ALGORITHMS`."""
    return {name: algo.load_class() for name, algo in ALGORITHMS.items()}


def stale_pages(docs_dir: Path = REPO_DOCS_DIR) -> list[Path]:
    """The pages whose committed table differs from the generated one."""
    stale = []
    for name, cls in algorithm_classes().items():
        path = page_path(name, docs_dir)
        if committed_block(read_page(path), path) != generated_block(cls):
            stale.append(path)
    return stale


def write_tables(docs_dir: Path = REPO_DOCS_DIR) -> list[Path]:
    """Rewrite the stale tables in place; returns the pages that changed."""
    changed = stale_pages(docs_dir)
    classes = algorithm_classes()
    for path in changed:
        page = path.read_text()
        path.write_text(replace_block(page, generated_block(classes[path.stem]), path))
    return changed


def main(argv: Sequence[str] | None = None, docs_dir: Path = REPO_DOCS_DIR) -> int:
    """Check the tables (exit status 1 where one is stale or cannot be generated) or, with ``--write``, rewrite them.

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    :param docs_dir: the folder of the pages (``--docs-dir`` when not given).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--write", action="store_true", help="rewrite the stale tables in place (default: only check)")
    parser.add_argument("--docs-dir", type=Path, default=docs_dir, help=f"folder of the pages (default: {docs_dir})")
    args = parser.parse_args(argv)
    try:
        if args.write:
            for path in write_tables(args.docs_dir):
                print(f"rewrote the Parameters table of {path}")
            return 0
        stale = stale_pages(args.docs_dir)
    except ValueError as error:  # a page without its markers, an argument without its :param: entry
        print(f"error: {error}", file=sys.stderr)
        return 1
    for path in stale:
        print(f"{path}: the Parameters table differs from the docstring; run {REGENERATE}")
    return 1 if stale else 0


__all__ = [
    "BEGIN",
    "END",
    "REGENERATE",
    "REPO_DOCS_DIR",
    "algorithm_classes",
    "committed_block",
    "generated_block",
    "listed",
    "main",
    "missing_params",
    "page_path",
    "param_docs",
    "read_page",
    "render_table",
    "replace_block",
    "sphinx_to_markdown",
    "stale_pages",
    "unknown_params",
]


if __name__ == "__main__":
    sys.exit(main())
