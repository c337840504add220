"""Sphinx configuration of the HTML book (``make book``): the notebooks with their committed
outputs, the README's headline table on the front page, ``paper/`` (results, method,
reproduction report), every page of ``docs/``, the CLI and the API reference.

The source folder is the repository root (``sphinx-build -c docs/book . OUT``), so notebooks and
reports link to ``../figures/...`` exactly as they do on GitHub; ``include_patterns`` picks the
book's pages. Nothing is executed and nothing is fetched: the book builds and opens offline.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from ibt.book import (  # noqa: E402
    HEADLINE_PLACEHOLDER,
    front_page_headline,
    rebase_output_links,
    write_api_pages,
)

project = "Imitation-BT"
author = "the Imitation-BT authors"
copyright = "the Imitation-BT authors, MIT licence"

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinxarg.ext",
    "sphinx-mathjax-offline",
]

root_doc = "docs/book/index"
include_patterns = [
    "docs/book/**",
    "docs/*.md",
    "notebooks/[0-9]*.ipynb",
    "paper/*.md",
]
exclude_patterns = [
    ".git", ".venv", "build", "data", "tests", "ibt", "**/.ipynb_checkpoints", "docs/book/conf.py",
]

# notebooks: the committed outputs, never re-executed
nb_execution_mode = "off"
nb_merge_streams = True
# Markdown outputs read as the cells do: tables, and links to pages and files of the book
nb_render_markdown_format = "myst"
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# API reference: members documented from their docstrings
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# a package documents what it defines: its re-exports are documented where they are defined
autodoc_default_options = {"members": True, "ignore-module-all": True}
autodoc_inherit_docstrings = False
napoleon_google_docstring = True

html_theme = "sphinx_book_theme"
html_title = "Imitation-BT"
highlight_language = "none"  # blocks that name no language (usage lines) stay plain
smartquotes = False  # `--refresh` and "quotes" stay as typed
html_last_updated_fmt = None
html_copy_source = False
html_show_sourcelink = False
html_theme_options = {
    "show_toc_level": 2,
    "home_page_in_toc": True,
    "use_download_button": False,
    "use_fullscreen_button": False,
}
html_context = {"default_mode": "auto"}  # light or dark as the reader's system is
suppress_warnings = ["myst.header"]


def _api_pages(app: object) -> None:
    """The API reference's pages, one per sub-package, written before Sphinx looks for sources."""
    write_api_pages(ROOT / "docs" / "book" / "api")


def _notebook_links(app, docname: str, source: list[str]) -> None:
    """Links in a notebook's Markdown outputs that were written from the repository's root,
    rebased onto the notebook's folder (see :func:`ibt.book.rebase_output_links`); the front
    page's placeholder replaced by the README's headline table."""
    path = Path(app.env.doc2path(docname))
    if path.suffix == ".ipynb":
        source[0] = rebase_output_links(source[0], path.parent, ROOT)
    elif HEADLINE_PLACEHOLDER in source[0]:
        readme = (ROOT / "README.md").read_text(encoding="utf-8")
        table = front_page_headline(readme, path.parent.relative_to(ROOT).as_posix())
        source[0] = source[0].replace(HEADLINE_PLACEHOLDER, table)


def _foreign_member(app: object, what: str, name: str, obj: object, skip: bool,
                    options: object) -> bool | None:
    """Skip members another library adds to our classes (scikit-learn's metadata requests)."""
    module = getattr(obj, "__module__", None) or "ibt"
    return True if not module.startswith("ibt") else None


REDIRECT = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Imitation-BT</title>
<meta http-equiv="refresh" content="0; url=docs/book/index.html"></head>
<body><p><a href="docs/book/index.html">Imitation-BT: the book</a></p></body></html>
"""


def _front_door(app, exception: Exception | None) -> None:
    """``index.html`` at the top of the book, which opens its front page (``docs/book/``)."""
    if exception is None and app.builder.format == "html":
        (Path(app.outdir) / "index.html").write_text(REDIRECT, encoding="utf-8")


def setup(app):
    app.connect("builder-inited", _api_pages)
    app.connect("source-read", _notebook_links)
    app.connect("autodoc-skip-member", _foreign_member)
    app.connect("build-finished", _front_door)
