"""The HTML book (``make book``): its API pages, and a check of every page in headless Chromium.

The book's sources are the notebooks, ``paper/`` and ``docs/`` (Sphinx + myst-nb, configured in
``docs/book/conf.py``), and the README's headline table on its front page. This module checks
the notebooks before Sphinx reads them, writes the front page's table and the API reference's
pages (one per sub-package, so a new module appears without editing the book), loads every
built page in headless Chromium and reports what a reader would meet: a page that does not
load, a link to a page or anchor that is not there, an image that does not show, a JavaScript
error or a file the page fails to load.

    python -m ibt.book notebooks NOTEBOOK...        # exit 2 and one line for a broken one
    python -m ibt.book check build/book/html        # exit 1 and one line per problem
    python -m ibt.book screenshot build/book/html index.html front.png
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import shutil
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlsplit

from ibt.files import atomic_write_text

if TYPE_CHECKING:
    from selenium.webdriver.chrome.webdriver import WebDriver

PACKAGE_ROOT = Path(__file__).resolve().parent
#: modules the API reference leaves out: ``__main__`` runs the CLI when imported
SKIPPED_MODULES = ("ibt.__main__",)
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
DRIVERS = ("chromedriver",)

#: what one page reports, read in the page itself after it loaded
_PAGE_SCRIPT = """
return {
  links: Array.from(document.querySelectorAll('a[href]'), a => a.href),
  images: Array.from(document.images, i => ({src: i.currentSrc || i.src,
                                             complete: i.complete, width: i.naturalWidth})),
  ids: Array.from(document.querySelectorAll('[id], a[name]'), e => e.id || e.name),
  ready: document.readyState,
};
"""


# ---------------------------------------------------------------- the API reference's pages


def _module_names() -> list[str]:
    """Every module of ``ibt``, read off the files (nothing is imported)."""
    names = []
    for path in PACKAGE_ROOT.rglob("*.py"):
        parts = path.relative_to(PACKAGE_ROOT.parent).with_suffix("").parts
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return sorted(n for n in names if n not in SKIPPED_MODULES)


def api_modules() -> dict[str, list[str]]:
    """Every module of ``ibt``, grouped by page: ``ibt`` (the package and its top-level modules)
    and one entry per sub-package, in name order."""
    pages: dict[str, list[str]] = {}
    for name in _module_names():
        top = ".".join(name.split(".")[:2])
        is_package = (PACKAGE_ROOT.parent / top.replace(".", os.sep)).is_dir()
        pages.setdefault(top if is_package else "ibt", []).append(name)
    return dict(sorted(pages.items()))


def shadowed_names(init: Path, submodules: set[str]) -> dict[str, str]:
    """Names a package's ``__init__.py`` defines that are also names of its submodules
    (``ibt.cli.main`` can be both a function and a module), each with the autodoc directive of
    what the package defines there."""
    found = {}
    for node in ast.parse(init.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            if node.name in submodules:
                found[node.name] = ("autoclass" if isinstance(node, ast.ClassDef)
                                    else "autofunction")
    return found


def api_page(page: str, modules: list[str]) -> str:
    """One page of the API reference: every module of a sub-package, members from docstrings.

    A package function named like one of its submodules is shown without an index entry (one
    name cannot point to both); the submodule keeps the name."""
    lines = [f"# `{page}`", ""]
    for module in modules:
        if module != page:
            lines += [f"## `{module}`", ""]
        shadowed = (shadowed_names(
            PACKAGE_ROOT.parent.joinpath(*page.split("."), "__init__.py"),
            {m.rpartition(".")[2] for m in modules if m.count(".") == page.count(".") + 1})
            if module == page and page != "ibt" else {})
        lines += ["```{eval-rst}", f".. automodule:: {module}", "   :members:",
                  "   :show-inheritance:"]
        if shadowed:
            lines += [f"   :exclude-members: {', '.join(sorted(shadowed))}", ""]
            for name, kind in sorted(shadowed.items()):
                lines += [f".. {kind}:: {module}.{name}", "   :no-index:", ""]
        lines += ["```", ""]
    return "\n".join(lines)


def write_api_pages(folder: Path) -> list[str]:
    """Write ``folder/index.md`` and one page per sub-package; rewrite only pages that changed
    (Sphinx then rereads only those). Returns the page names."""
    folder.mkdir(parents=True, exist_ok=True)
    pages = api_modules()
    texts = {f"{page}.md": api_page(page, modules) for page, modules in pages.items()}
    toc = "\n".join(pages)
    texts["index.md"] = ("# API reference\n\nGenerated from the docstrings at every build: one "
                         "page per sub-package of `ibt`, in name order (how they depend on one "
                         "another: `docs/ARCHITECTURE.md`).\n\n```{toctree}\n:maxdepth: 1\n\n"
                         f"{toc}\n```\n")
    for stale in folder.glob("*.md"):
        if stale.name not in texts:
            stale.unlink()
    for name, text in texts.items():
        path = folder / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            atomic_write_text(path, text)
    return list(pages)


# ---------------------------------------------------------------- notebooks' Markdown outputs

_MD_LINK = re.compile(r"(\]\()([^)\s#]+)([^)]*\))")


def rebase_output_links(notebook_text: str, notebook_dir: Path, root: Path) -> str:
    """A notebook's JSON with the links of its Markdown outputs rebased onto its own folder.

    A Markdown output written for the repository's root (notebook 09 shows the README's results
    block) links from there, e.g. ``figures/front.png``; from ``notebooks/`` in the book that
    points nowhere. A link that names no file from the notebook's folder but one from the root
    is rewritten relative to the notebook; every other link, and the rest of the file, is kept.
    """
    notebook = json.loads(notebook_text)

    def rebase(match: re.Match[str]) -> str:
        target = match.group(2)
        if urlsplit(target).scheme or target.startswith("/") or (notebook_dir / target).exists():
            return match.group(0)
        if not (root / target).exists():
            return match.group(0)
        moved = os.path.relpath(root / target, notebook_dir).replace(os.sep, "/")
        return f"{match.group(1)}{moved}{match.group(3)}"

    changed = False
    for cell in notebook.get("cells", []):
        for output in cell.get("outputs", []):
            data = output.get("data", {})
            if "text/markdown" not in data:
                continue
            text = data["text/markdown"]
            text = "".join(text) if isinstance(text, list) else text
            new = _MD_LINK.sub(rebase, text)
            if new != text:
                data["text/markdown"], changed = new, True
    return json.dumps(notebook, indent=1, ensure_ascii=False) if changed else notebook_text


# ---------------------------------------------------------------- the notebooks it reads


def notebook_problem(path: Path) -> str | None:
    """One line naming what makes ``path`` unreadable as a notebook (truncated JSON, not a
    notebook, invalid against nbformat's schema) and the fix; None for a valid notebook.

    Checked before Sphinx reads the notebooks, whose own error would be a traceback."""
    import nbformat

    fix = f"restore it with `git checkout -- {path}` or re-run it (make figures)"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        return f"{path} is not a notebook (not UTF-8 text): {fix}"
    except json.JSONDecodeError as err:
        return f"{path} is not a notebook (broken or truncated JSON at line {err.lineno}): {fix}"
    if not isinstance(data, dict) or not isinstance(data.get("nbformat"), int):
        return f"{path} is not a notebook (no nbformat version): {fix}"
    try:
        nbformat.validate(data)
    except nbformat.ValidationError as err:
        reason = " ".join(str(err.message).split())[:200]
        return f"{path} is not a valid notebook ({reason}): {fix}"
    return None


# ---------------------------------------------------------------- the front page's headline

#: where the front page takes the README's headline table
HEADLINE_PLACEHOLDER = "<!-- the README's headline table -->"


def front_page_headline(readme_text: str, page_dir: str) -> str:
    """The README's generated headline table, for a page in ``page_dir`` (relative to the root).

    The README links from the repository's root; each link is rebased onto ``page_dir``. A link
    to a folder (the BT's folder, which GitHub lists) keeps only its text: a book holds files.
    """
    from ibt.report.markdown import HEADLINE_BEGIN, HEADLINE_END

    if HEADLINE_BEGIN not in readme_text or HEADLINE_END not in readme_text:
        raise ValueError(f"README.md lacks the headline markers {HEADLINE_BEGIN!r} ... "
                         f"{HEADLINE_END!r}: run notebooks/12_headline.ipynb")
    block = readme_text.split(HEADLINE_BEGIN, 1)[1].split(HEADLINE_END, 1)[0].strip()
    up = "/".join(".." for part in Path(page_dir).parts if part not in ("", "."))

    def rebase(match: re.Match[str]) -> str:
        text, target = match.group(1), match.group(2)
        if urlsplit(target).scheme or target.startswith(("/", "#")):
            return match.group(0)
        if target.endswith("/"):
            return text
        return f"{text}({up}/{target})" if up else match.group(0)

    return re.sub(r"(\[[^\]]*\])\(([^)\s]+)\)", rebase, block)


# ---------------------------------------------------------------- the browser check


@dataclass(frozen=True)
class Problem:
    """One thing a reader would meet on one page."""

    page: str
    kind: str  # "load", "link", "image", "console"
    detail: str

    def __str__(self) -> str:
        return f"{self.page}: {self.kind}: {self.detail}"


def find_browser() -> tuple[str, str] | None:
    """Paths of Chromium and its driver, or None when either is missing."""
    browser = next((p for p in map(shutil.which, BROWSERS) if p), None)
    driver = next((p for p in map(shutil.which, DRIVERS) if p), None)
    return (browser, driver) if browser and driver else None


@contextmanager
def headless_chromium(width: int = 1280, height: int = 900) -> Iterator[WebDriver]:
    """Headless Chromium that keeps its console log; it never reaches the network."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    found = find_browser()
    if found is None:
        raise FileNotFoundError("headless Chromium is missing: install it with "
                                "'apt-get install -y chromium chromium-driver'")
    browser, driver_path = found
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--hide-scrollbars",
                 "--allow-file-access-from-files", f"--window-size={width},{height}",
                 "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(executable_path=driver_path))
    try:
        driver.set_page_load_timeout(60)
        yield driver
    finally:
        driver.quit()


def html_pages(html_dir: Path) -> list[Path]:
    """Every HTML page of a built book, sources and static files left out."""
    skip = {"_sources", "_static", "_images", "_downloads", ".doctrees"}
    return sorted(p for p in html_dir.rglob("*.html")
                  if not skip & set(p.relative_to(html_dir).parts[:-1]))


def _local_file(url: str) -> tuple[Path, str] | None:
    """(file, fragment) of a ``file://`` URL; None for any other scheme."""
    parts = urlsplit(url)
    if parts.scheme != "file":
        return None
    return Path(unquote(parts.path)), unquote(parts.fragment)


def _target_page(path: Path) -> Path:
    return path / "index.html" if path.is_dir() else path


def check_pages(html_dir: str | Path, pages: Iterable[Path] | None = None) -> list[Problem]:
    """Load each page (default: all of them) in headless Chromium; return every problem found.

    Links and images are checked on disk, anchors against the ids of the page they point to,
    images also by whether the browser decoded them; console messages at level SEVERE
    (JavaScript errors, files that failed to load) are problems. Links off the book (http, mailto)
    are not followed: the book must open offline, so nothing it needs may be there.
    """
    root = Path(html_dir).resolve()
    chosen = [Path(p).resolve() for p in (pages if pages is not None else html_pages(root))]
    problems: list[Problem] = []
    ids: dict[Path, set[str]] = {}
    anchors: list[tuple[str, Path, str]] = []
    with headless_chromium() as driver:
        for page in chosen:
            name = page.relative_to(root).as_posix()
            if not page.is_file():
                problems.append(Problem(name, "load", "no such file"))
                continue
            driver.get(page.as_uri())
            seen = _settled(driver)
            if not driver.current_url.startswith("file:") or seen["ready"] != "complete":
                problems.append(Problem(name, "load", f"did not load ({driver.current_url})"))
                continue
            ids[page] = set(seen["ids"])
            problems += _page_problems(root, name, seen, anchors)
            problems += [Problem(name, "console", entry["message"])
                         for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
        for name, target, fragment in anchors:
            if target not in ids and target.suffix == ".html":
                ids[target] = _ids_on_disk(target)
            if target in ids and fragment not in ids[target]:
                problems.append(Problem(name, "link", f"no anchor #{fragment} in "
                                        f"{_shown(target, root)}"))
    return problems


def _settled(driver: WebDriver, seconds: float = 10.0) -> dict[str, Any]:
    """What the page holds once it stopped moving (a redirect unloads it while it is read)."""
    import time

    from selenium.common.exceptions import WebDriverException

    deadline = time.monotonic() + seconds
    url, seen = driver.current_url, None
    while time.monotonic() < deadline:
        try:
            seen = driver.execute_script(_PAGE_SCRIPT)
        except WebDriverException:
            seen = None
        now = driver.current_url
        if seen is not None and seen["ready"] == "complete" and now == url:
            return dict(seen)
        url = now
        time.sleep(0.05)
    return dict(seen or {"ready": "timeout", "links": [], "images": [], "ids": []})


def _page_problems(root: Path, name: str, seen: dict[str, Any],
                   anchors: list[tuple[str, Path, str]]) -> list[Problem]:
    """Missing link targets and images of one page; anchors to check are appended. A file
    outside the book counts as missing: the book is read without the repository beside it."""
    problems = []
    for url in dict.fromkeys(seen["links"]):
        local = _local_file(url)
        if local is None:
            continue
        path, fragment = local
        target = _target_page(path)
        if not target.exists() or not target.resolve().is_relative_to(root):
            problems.append(Problem(name, "link", f"{url} points to no file of the book"))
        elif fragment:
            anchors.append((name, target, fragment))
    for image in seen["images"]:
        local = _local_file(image["src"])
        if local is not None and not (local[0].is_file()
                                      and local[0].resolve().is_relative_to(root)):
            problems.append(Problem(name, "image", f"{image['src']} is not in the book"))
        elif not image["complete"] or image["width"] == 0:
            problems.append(Problem(name, "image", f"{image['src']} did not show"))
    return problems


def _ids_on_disk(page: Path) -> set[str]:
    """Ids of a page the check did not load (one outside the chosen pages)."""
    import re

    text = page.read_text(encoding="utf-8", errors="replace")
    return set(re.findall(r'\b(?:id|name)="([^"]+)"', text))


def _shown(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return str(path)


def screenshot(html_dir: str | Path, page: str, output: str | Path, width: int = 1280,
               height: int = 900) -> Path:
    """A PNG of one page of the built book as headless Chromium shows it (atomic write);
    ``page#anchor`` scrolls to that anchor first."""
    name, _, anchor = page.partition("#")
    path = Path(html_dir).resolve() / name
    if not path.is_file():
        raise FileNotFoundError(f"{path} is not a page of the built book: run `make book` first")
    if anchor and anchor not in _ids_on_disk(path):
        raise FileNotFoundError(f"{name} has no anchor #{anchor}: pick one of its section ids")
    with headless_chromium(width, height) as driver:
        driver.get(path.as_uri())
        _settled(driver)
        if anchor:  # scrolled to, not navigated to: the theme would highlight a target
            driver.execute_script("document.getElementById(arguments[0]).scrollIntoView();"
                                  "window.scrollBy(0, -50);", anchor)
        png = driver.get_screenshot_as_png()
    from ibt.files import atomic_write_bytes

    atomic_write_bytes(output, png)
    return Path(output)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ibt.book", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    notebooks = sub.add_parser("notebooks", help="check that the notebooks the book reads are "
                               "valid (exit 2 and one line naming the first that is not)")
    notebooks.add_argument("paths", nargs="+", type=Path)
    check = sub.add_parser("check", help="load every page in headless Chromium")
    check.add_argument("html_dir")
    shot = sub.add_parser("screenshot", help="a PNG of one page")
    shot.add_argument("html_dir")
    shot.add_argument("page", help="the page's path in the book, e.g. index.html or "
                      "notebooks/07_front.html#the-front")
    shot.add_argument("output")
    shot.add_argument("--width", type=int, default=1280)
    shot.add_argument("--height", type=int, default=900)
    args = parser.parse_args(argv)
    if args.command == "notebooks":
        for path in args.paths:
            broken = (f"no notebook at {path}: give paths such as notebooks/00_quickstart.ipynb"
                      if not path.is_file() else notebook_problem(path))
            if broken:
                print(broken, file=sys.stderr)
                return 2
        return 0
    html_dir = Path(args.html_dir)
    if not (html_dir / "index.html").is_file():
        print(f"{html_dir} holds no built book (no index.html): run `make book` first",
              file=sys.stderr)
        return 2
    if find_browser() is None:
        print("headless Chromium is missing: install it with "
              "'apt-get install -y chromium chromium-driver'", file=sys.stderr)
        return 2
    if args.command == "screenshot":
        try:
            screenshot(html_dir, args.page, args.output, args.width, args.height)
        except FileNotFoundError as err:
            print(err, file=sys.stderr)
            return 2
        return 0
    problems = check_pages(html_dir)
    for problem in problems:
        print(problem)
    print(f"{len(html_pages(html_dir))} pages checked, {len(problems)} problems",
          file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    raise SystemExit(main())
