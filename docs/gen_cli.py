"""The command-line reference, rendered from the parsers (``material_structures.cli.build_parser()``).

An MkDocs hook (``hooks:`` in mkdocs.yml): at build time it replaces the marker line ``<!-- cli-reference -->``
in ``cli.md`` with one section per subcommand, each holding that subcommand's ``--help`` text, so the
reference is never a hand-written copy. ``python docs/gen_cli.py`` prints the same Markdown.
"""

from __future__ import annotations

import argparse
import os

MARKER = "<!-- cli-reference -->"
PAGE = "cli.md"
WIDTH = "100"  # columns argparse wraps help text to, so that the page does not depend on the terminal


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:  # argparse keeps subcommands only here
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices.items())
    return []


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    yield path, parser
    for name, sub in _subparsers(parser):
        yield from _walk(sub, path + (name,))


def render() -> str:
    """Markdown for every (sub)command: a heading per command path and its help in a code block."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        from material_structures.cli import build_parser

        root = build_parser()
        parts = []
        for path, parser in _walk(root, ()):
            level = "#" * min(2 + max(len(path) - 1, 0), 4)
            title = " ".join(path) if path else "python -m material_structures"
            parts.append(f"{level} {title}\n\n```text\n{parser.format_help().rstrip()}\n```\n")
        return "\n".join(parts)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def on_page_markdown(markdown: str, page, config, files) -> str:  # MkDocs hook
    if page.file.src_uri == PAGE and MARKER in markdown:
        return markdown.replace(MARKER, render())
    return markdown


if __name__ == "__main__":
    print(render())
