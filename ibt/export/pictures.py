"""Drawings rendered to files: measured against the README's width, fitted, saved, composed.

A drawing is saved as SVG and PNG (the PNG at :data:`ibt.export.drawing.DRAWING_DPI`, stamped
with its smallest font, :mod:`ibt.export.readable`); :func:`draw_bt` staggers or collapses a
BT that is too wide and writes the full tree as an SVG beside it; :func:`compose` lays panels
side by side.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

from ibt.bt.model import BehaviorTree
from ibt.export.drawing import (
    DRAWING_DPI,
    require_dot,
    to_graphviz,
)
from ibt.export.readable import MAX_ASPECT, max_width_px, stamp_info, text_pt_at_readme_width
from ibt.files import atomic_target, atomic_write_bytes


# ------------------------------------------------------------------------- measuring, saving
@dataclass(frozen=True)
class Layout:
    """A rendered graph's size in points and the smallest font graphviz drew."""

    width_pt: float
    height_pt: float
    min_font_pt: float

    @property
    def aspect(self) -> float:
        return self.width_pt / self.height_pt

    def text_pt(self, dpi: float = DRAWING_DPI) -> float:
        """Smallest text at README width when rendered at ``dpi``."""
        return text_pt_at_readme_width(self.min_font_pt, dpi, self.width_pt * dpi / 72)

    @property
    def readable(self) -> bool:
        return (self.width_pt * DRAWING_DPI / 72 <= max_width_px(self.min_font_pt, DRAWING_DPI)
                and self.aspect <= MAX_ASPECT)


def measure_graph(graph) -> Layout:
    """Lay ``graph`` out (SVG, 72 pt per inch) and read its size and smallest font."""
    require_dot()
    plain = graph.copy()
    plain.graph_attr.pop("dpi", None)
    svg = plain.pipe(format="svg").decode()
    size = re.search(r'<svg width="([\d.]+)pt" height="([\d.]+)pt"', svg)
    if size is None:
        raise RuntimeError("graphviz wrote an SVG without a size in pt; is `dot` graphviz?")
    fonts = [float(f) for f in re.findall(r'font-size="([\d.]+)"', svg)]
    return Layout(float(size.group(1)), float(size.group(2)), min(fonts) if fonts else 14.0)


def save_drawing(graph, stem: str | Path, formats: tuple[str, ...] = ("svg", "png")
                 ) -> list[Path]:
    """Render ``graph`` to ``<stem>.<fmt>`` for each format, atomically; PNGs are rendered at
    :data:`DRAWING_DPI` and stamped with their smallest font (:mod:`ibt.export.readable`)."""
    require_dot()
    stem = Path(stem)
    written = []
    for fmt in formats:
        target = stem.with_suffix(f".{fmt}")
        if fmt == "png":
            layout = measure_graph(graph)
            hi = graph.copy()
            hi.graph_attr["dpi"] = str(DRAWING_DPI)
            _save_png(hi.pipe(format="png"), target, layout.min_font_pt, DRAWING_DPI)
        else:
            atomic_write_bytes(target, graph.pipe(format=fmt))
        written.append(target)
    return written


def _save_png(data: bytes, target: Path, font_pt: float, dpi: float, kind: str = "tree"
              ) -> None:
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for key, value in stamp_info(font_pt, dpi, kind).items():
        info.add_text(key, value)
    with Image.open(io.BytesIO(data)) as image, atomic_target(target) as tmp:
        image.save(tmp, format="png", pnginfo=info, optimize=True)


def fit_graphviz(bt: BehaviorTree, highlight: dict[int, bool] | None = None,
                 precision: int = 4, *, deciding: int | None = None,
                 title: str | None = None, collapse: bool | None = None,
                 full_name: str | None = None, legend: bool = True):
    """The first readable drawing of: the full tree, then the tree collapsed per child of the
    root, those children spread over 1, 2, 3, 4, 6, 8, ... rows.

    Returns ``(graph, collapsed)``; when nothing is readable, the last (most compact) try.
    ``collapse`` forces (True) or forbids (False) the collapsed view; ``full_name`` (the file
    with every node) is named in a collapsed drawing's title.
    """
    n_children = len(getattr(bt.root, "children", ()))
    tries = [(False, 1)] if collapse is not True else []
    if collapse is not False:
        tries += [(True, rows) for rows in sorted({1, 2, 3, 4, *range(6, n_children + 1, 2)})
                  if rows == 1 or rows <= n_children]
    graph = None
    for collapsed, rows in tries:
        note = title
        if collapsed:
            note = "\n".join(filter(None, [title, "(one node per action" + (
                f"; every node: {full_name})" if full_name else ")")]))
        graph = to_graphviz(bt, highlight, precision, deciding=deciding, collapse=collapsed,
                            stagger=rows, title=note, legend=legend)
        if measure_graph(graph).readable:
            return graph, collapsed
    return graph, tries[-1][0]


@dataclass(frozen=True)
class Drawing:
    """What :func:`draw_bt` wrote."""

    png: Path
    svg: Path
    collapsed: bool


def draw_bt(bt: BehaviorTree, stem: str | Path, highlight: dict[int, bool] | None = None,
            precision: int = 4, *, deciding: int | None = None, title: str | None = None
            ) -> Drawing:
    """``<stem>.png``, readable at README width (collapsed per action if it must be), and
    ``<stem>.svg`` with every node of the tree."""
    graph, collapsed = fit_graphviz(bt, highlight, precision, deciding=deciding, title=title,
                                    full_name=f"{Path(stem).name}.svg")
    full_title = f"{title} (every node)" if collapsed and title else title
    png = save_drawing(graph, stem, formats=("png",))[0]
    full = to_graphviz(bt, highlight, precision, deciding=deciding, title=full_title)
    svg = save_drawing(full, stem, formats=("svg",))[0]
    return Drawing(png, svg, collapsed)


# ------------------------------------------------------------------------------ composing
def compose(panels: list[str | Path], path: str | Path, columns: int | None = None,
            gap_px: int = 24, formats: tuple[str, ...] = ("png",)) -> list[Path]:
    """Panels (stamped PNGs of one dpi) pasted at their own pixel size, so all share one
    scale, in rows of ``columns`` (default: as many as stay readable at README width).

    Writes ``path`` with the suffix of each format (``pdf`` is the same raster).
    """
    from PIL import Image

    from ibt.export.readable import measure

    infos = [measure(p) for p in panels]
    dpis = {info.dpi for info in infos}
    if len(dpis) != 1:
        raise ValueError(f"panels must share one dpi to share one scale, got {sorted(dpis)}")
    dpi = dpis.pop()
    font = min(info.font_pt for info in infos)
    kind = "tree" if any(info.kind == "tree" for info in infos) else "plot"
    budget = max_width_px(font, dpi)

    def rows_of(n: int) -> list[list[int]]:
        return [list(range(i, min(i + n, len(infos)))) for i in range(0, len(infos), n)]

    def width(rows: list[list[int]]) -> int:
        return max(sum(infos[i].width_px for i in row) + gap_px * (len(row) - 1)
                   for row in rows)

    if columns is None:
        columns = 1
        for n in range(len(infos), 0, -1):
            if width(rows_of(n)) <= budget:
                columns = n
                break
    rows = rows_of(columns)
    total_w = width(rows)
    heights = [max(infos[i].height_px for i in row) for row in rows]
    canvas = Image.new("RGB", (total_w, sum(heights) + gap_px * (len(rows) - 1)), "white")
    y = 0
    for row, height in zip(rows, heights, strict=True):
        row_w = sum(infos[i].width_px for i in row) + gap_px * (len(row) - 1)
        x = (total_w - row_w) // 2
        for i in row:
            with Image.open(panels[i]) as image:
                canvas.paste(image.convert("RGB"), (x, y))
            x += infos[i].width_px + gap_px
        y += height + gap_px
    written = []
    path = Path(path)
    for fmt in formats:
        target = path.with_suffix(f".{fmt}")
        if fmt == "png":
            buffer = io.BytesIO()
            canvas.save(buffer, format="png")
            _save_png(buffer.getvalue(), target, font, dpi, kind)
        else:
            # fixed metadata (Pillow stamps the time and the temporary file's name otherwise),
            # so the same panels always make the same bytes
            fixed = ({"title": target.stem, "creationDate": None, "modDate": None}
                     if fmt == "pdf" else {})
            with atomic_target(target) as tmp:
                canvas.save(tmp, format=fmt, resolution=dpi, **fixed)
        written.append(target)
    return written
