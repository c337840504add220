"""The HTML book (``make book``): it builds offline with no warning, holds every notebook with its
committed outputs, ``paper/`` (results, method, report), every page of ``docs/``, the README's
headline table on its front page, the CLI and the API, and every page opens in headless
Chromium with no broken link, missing image or JavaScript error. A broken notebook stops
``make book`` before Sphinx with exit 2 and one line naming it.

The browser half needs Debian's ``chromium`` and ``chromium-driver`` (``.ci/run`` installs them);
without them it skips, except under CI (``CI`` set), where it fails.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from ibt import book
from ibt.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted(ROOT.glob("notebooks/[0-9]*.ipynb"))


def _need_browser() -> None:
    if book.find_browser() is None:
        message = ("headless Chromium is missing: apt-get install -y chromium chromium-driver "
                   "(.ci/run does when it runs as root)")
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)


@pytest.fixture(scope="module")
def html(tmp_path_factory) -> Path:
    """A fresh build of the book (what ``make book`` runs), warnings being errors."""
    out = tmp_path_factory.mktemp("book")
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-q", "-W", "--keep-going", "-b", "html",
         "-c", "docs/book", "-d", str(out / "doctrees"), ".", str(out / "html")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr[-4000:]
    return out / "html"


def test_the_book_holds_every_part(html):
    # Expect: a page per notebook, every page of paper/ and docs/ (what the README links), the
    # CLI and the API reference
    pages = {p.relative_to(html).as_posix() for p in book.html_pages(html)}
    expected = {f"notebooks/{nb.stem}.html" for nb in NOTEBOOKS} | {
        "index.html", "docs/book/index.html", "docs/book/cli.html", "docs/book/api/index.html"}
    expected |= {f"{md.parent.name}/{md.stem}.html" for md in [
        *ROOT.glob("paper/*.md"), *ROOT.glob("docs/*.md")]}
    assert {"paper/results.html", "paper/method.html", "docs/deploy.html",
            "docs/hostile.html"} <= expected
    assert expected <= pages, sorted(expected - pages)
    assert {f"docs/book/api/{page}.html" for page in book.api_modules()} <= pages


def test_the_front_page_shows_the_headline_table(html):
    # Expect: one table row per headline BT (a BT in two roles is one row), each with its
    # drawing and its GIF in the book
    headline = pd.read_csv(ROOT / "data" / "results" / "headline.csv").drop_duplicates(
        "json_file")
    front = (html / "docs" / "book" / "index.html").read_text()
    table = front.split('id="the-headline"', 1)[1].split("</table>", 1)[0]
    assert table.count("<tr") == len(headline) + 1  # and the header row
    for suffix in ("bt.png", "episode.gif"):
        links = re.findall(rf'href="([^"]*/{re.escape(suffix)})"', table)
        assert len(links) == len(headline), suffix
        front_dir = html / "docs" / "book"
        assert all((front_dir / link).is_file() for link in links), links


def test_notebooks_show_their_committed_outputs(html):
    # Expect: every output image of a notebook is in its page (nothing re-run, nothing dropped)
    for notebook in NOTEBOOKS:
        cells = json.loads(notebook.read_text())["cells"]
        images = sum("image/png" in o.get("data", {}) or "image/svg+xml" in o.get("data", {})
                     for c in cells for o in c.get("outputs", []))
        page = (html / "notebooks" / f"{notebook.stem}.html").read_text()
        shown = len(re.findall(r'<div class="cell_output', page))
        assert page.count("<img") >= images, notebook.name
        assert shown == sum(bool(c.get("outputs")) for c in cells), notebook.name


def test_cli_and_api_pages_are_generated(html):
    # Expect: every subcommand and option of the parser on the CLI page, every module on the
    # API pages
    parser = build_parser()
    subcommands = next(a for a in parser._actions if a.dest == "command").choices
    cli = (html / "docs" / "book" / "cli.html").read_text()
    text = re.sub(r"<[^>]+>", "", cli)
    for name, sub in subcommands.items():
        assert f'id="python-m-ibt-{name}"' in cli, name
        options = [o for a in sub._actions for o in a.option_strings if o.startswith("--")]
        assert all(option in text for option in options), name
    for page, modules in book.api_modules().items():
        page_text = (html / "docs" / "book" / "api" / f"{page}.html").read_text()
        assert all(f'id="module-{module}"' in page_text for module in modules), page


def test_every_page_opens_offline_without_problems(html):
    # Expect: every page loads; its links, anchors and images resolve; no console error
    _need_browser()
    problems = book.check_pages(html)
    assert not problems, "\n".join(map(str, problems))


def test_the_check_reports_planted_problems(html, tmp_path):
    # Expect: a copy of a page with a broken link, a broken anchor, a link out of the book (to
    # a file that exists), a missing image and a script error gets exactly those problems (the
    # image twice: not on disk, and the browser's failed load in the console); the page it
    # copies gets none
    _need_browser()
    copy = tmp_path / "html"
    shutil.copytree(html, copy, ignore=shutil.ignore_patterns("mathjax"))
    (tmp_path / "outside-the-book.html").write_text("<p>beside the book, not in it</p>")
    original = copy / "docs" / "format.html"
    planted = original.with_name("planted.html")
    planted.write_text(original.read_text().replace("</body>", (
        '<a href="no-such-page.html">x</a><a href="format.html#no-such-anchor">y</a>'
        '<a href="../../outside-the-book.html">o</a>'
        '<img src="../_images/no-such-image.png" alt="z">'
        '<script>throw new Error("planted error")</script></body>')))
    problems = book.check_pages(copy, [original, planted])
    found = {(p.page, p.kind,
              re.sub(r".*(no-such-\w+|planted error|outside-the-book).*", r"\1", p.detail))
             for p in problems}
    assert found == {("docs/planted.html", "link", "no-such-page"),
                     ("docs/planted.html", "link", "no-such-anchor"),
                     ("docs/planted.html", "link", "outside-the-book"),
                     ("docs/planted.html", "image", "no-such-image"),
                     ("docs/planted.html", "console", "no-such-image"),
                     ("docs/planted.html", "console", "planted error")}, problems


def test_markdown_outputs_written_from_the_root_link_from_the_notebook(tmp_path):
    # Expect: a link that resolves only from the repository root is rebased; others are kept
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"")
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "notebooks" / "b.png").write_bytes(b"")
    text = ("![a](figures/a.png) ![b](b.png) [c](https://example.org/x.png) "
            "[d](figures/none.png) [e](figures/a.png#top)")
    notebook = {"cells": [{"cell_type": "code", "outputs": [
        {"output_type": "display_data", "data": {"text/markdown": [text]}}]}]}
    out = json.loads(book.rebase_output_links(json.dumps(notebook), tmp_path / "notebooks",
                                              tmp_path))
    assert out["cells"][0]["outputs"][0]["data"]["text/markdown"] == (
        "![a](../figures/a.png) ![b](b.png) [c](https://example.org/x.png) "
        "[d](figures/none.png) [e](../figures/a.png#top)")
    unchanged = json.dumps({"cells": [{"cell_type": "markdown", "source": "[a](figures/a.png)"}]})
    assert book.rebase_output_links(unchanged, tmp_path / "notebooks", tmp_path) == unchanged


def test_api_pages_cover_every_module():
    # Expect: every module file of ibt is on one API page (bar __main__, which runs the CLI)
    files = {".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
             for p in (ROOT / "ibt").rglob("*.py")}
    listed = [m for modules in book.api_modules().values() for m in modules]
    assert sorted(listed) == sorted(files - {"ibt.__main__"})


def test_screenshot_of_a_page(html, tmp_path):
    # Expect: a PNG of the browser's window size; an anchor that is not there is refused
    _need_browser()
    png = book.screenshot(html, "notebooks/07_front.html#the-front", tmp_path / "a.png",
                          width=640, height=480)
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(data[16:20], "big") == 640
    with pytest.raises(FileNotFoundError, match="no anchor"):
        book.screenshot(html, "notebooks/07_front.html#nowhere", tmp_path / "b.png")
    assert not (tmp_path / "b.png").exists()


def test_command_line_refuses_a_folder_without_a_book(tmp_path, capsys):
    # Expect: exit 2 and one line naming the fix, for a folder that holds no built book
    assert book.main(["check", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "make book" in err


def test_a_package_function_named_like_its_submodule_is_not_indexed_twice(tmp_path):
    # Expect: only names the package itself defines (def or class) and a submodule carries
    init = tmp_path / "__init__.py"
    init.write_text("from x import y as checks\n\ndef main():\n    pass\n\nclass Tool:\n"
                    "    pass\n\ndef other():\n    pass\n")
    assert book.shadowed_names(init, {"main", "checks", "Tool", "commands"}) == {
        "main": "autofunction", "Tool": "autoclass"}


def test_the_front_pages_headline_links_from_its_folder():
    # Expect: links rebased from the root onto the page's folder, a folder link kept as text,
    # URLs and anchors untouched; a README without the markers is refused
    from ibt.report.markdown import HEADLINE_BEGIN, HEADLINE_END

    readme = (f"intro\n{HEADLINE_BEGIN}\n\n| a | [`bt`](figures/h/x/) ([drawing](figures/h/x/bt.png"
              f")) [u](https://example.org/a.png) [s](#top) |\n\n{HEADLINE_END}\nrest")
    assert book.front_page_headline(readme, "docs/book") == (
        "| a | [`bt`] ([drawing](../../figures/h/x/bt.png)) [u](https://example.org/a.png) "
        "[s](#top) |")
    assert "(figures/h/x/bt.png)" in book.front_page_headline(readme, ".")
    with pytest.raises(ValueError, match="headline markers"):
        book.front_page_headline("no table here", "docs/book")


BROKEN_NOTEBOOKS = {
    "truncated": lambda text: text[: len(text) // 2],
    "empty": lambda text: "",
    "not a notebook": lambda text: "[1, 2, 3]",
    "invalid": lambda text: text.replace('"cell_type": "code"', '"cell_type": "spreadsheet"', 1),
}


@pytest.mark.parametrize("how", BROKEN_NOTEBOOKS)
def test_a_broken_notebook_is_named_in_one_line(tmp_path, capsys, how):
    # Expect: exit 2 and one line naming the file and the fix; the committed notebooks pass
    good = (ROOT / "notebooks" / "00_quickstart.ipynb").read_text()
    broken = tmp_path / "05_broken.ipynb"
    broken.write_text(BROKEN_NOTEBOOKS[how](good))
    assert book.main(["notebooks", *map(str, NOTEBOOKS), str(broken)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(broken) in err and "git checkout" in err, err
    assert book.main(["notebooks", *map(str, NOTEBOOKS)]) == 0


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_book_stops_on_a_truncated_notebook(tmp_path):
    # Expect: `make book` exits 2 before Sphinx starts, our one line naming the notebook (make
    # adds its own "***" line)
    truncated = tmp_path / "03_truncated.ipynb"
    truncated.write_text((ROOT / "notebooks" / "03_distillation.ipynb").read_text()[:500])
    result = subprocess.run(["make", "-o", ".venv/.installed", "book", f"NOTEBOOKS={truncated}"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    ours = [line for line in result.stderr.splitlines() if not line.startswith("make")]
    assert len(ours) == 1 and str(truncated) in ours[0], result.stderr
    assert "sphinx" not in result.stdout.lower()
