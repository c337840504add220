"""Text from data on its way into Markdown (and the HTML a book renders from it).

:func:`md` is the one escaping helper of :mod:`ibt.report`: every table cell and sentence that
prints a field of a CSV or JSON file (a task or expert name, a status's evidence, a machine's
name) passes through it, so a ``<script>`` in ``data/experts/manifest.csv`` reaches a page as
the text ``<script>``, and a ``|`` cannot cut a table row.
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import quote

#: Markdown's and HTML's active characters in running text, and what each becomes
_ESCAPES = {"\\": "\\\\", "&": "&amp;", "<": "&lt;", ">": "&gt;", "|": "\\|", "[": "\\[",
            "]": "\\]", "`": "\\`"}
_ACTIVE = re.compile("|".join(map(re.escape, _ESCAPES)))


def md(value: Any) -> str:
    """``value`` as Markdown text that renders as itself: HTML's ``& < >`` as entities (no tag
    reaches the page), ``| [ ] ` \\`` escaped (no table cell cut, no link or code span made),
    line breaks as spaces (no new block)."""
    text = re.sub(r"[\r\n]+", " ", str(value))
    return _ACTIVE.sub(lambda m: _ESCAPES[m.group(0)], text)


def md_url(value: Any) -> str:
    """A path from data as a Markdown link's target: percent-encoded but for ``/``, so no
    ``)`` or space ends the link and no ``javascript:`` scheme is made of it."""
    return quote(str(value), safe="/._-~+")
