"""Is a figure readable where people read it? Text size at README width, and aspect ratio.

GitHub shows a README image at its own width, or scaled down to the text column (about 800 to
900 px; :data:`README_WIDTH_PX`). A PNG rendered at ``dpi`` whose smallest text is ``font_pt``
points shows that text, at README width, as

    font_pt * dpi / 96 * min(1, README_WIDTH_PX / png_width)   points

(96 CSS px per inch). Every figure this package writes carries, in its PNG text chunks, the
smallest font size it drew (read back from graphviz's SVG or from matplotlib's text objects) and
its dpi (:func:`stamp`), so a test can judge the committed PNGs from their pixels and these two
numbers (:func:`measure`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

README_WIDTH_PX = 850  #: the width at which a README shows a figure (GitHub: ~800-900 px)
MIN_TEXT_PT = 9.0  #: the smallest text a figure may show at README width
MAX_ASPECT = 3.0  #: the widest a tree drawing may be: width / height

KEY_FONT = "ibt:min-font-pt"
KEY_DPI = "ibt:dpi"
KEY_KIND = "ibt:kind"  # "tree" (a drawing of a tree or BT) or "plot"


def text_pt_at_readme_width(font_pt: float, dpi: float, width_px: float) -> float:
    """The size (pt) at which text of ``font_pt`` in a ``width_px``-wide PNG at ``dpi`` shows
    in a README."""
    return font_pt * dpi / 96.0 * min(1.0, README_WIDTH_PX / width_px)


def max_width_px(font_pt: float, dpi: float) -> float:
    """The widest PNG whose ``font_pt`` text still shows at :data:`MIN_TEXT_PT`."""
    return README_WIDTH_PX * font_pt * dpi / 96.0 / MIN_TEXT_PT


def stamp_info(font_pt: float, dpi: float, kind: str) -> dict[str, str]:
    """PNG text chunks recording how the figure was drawn (see :func:`measure`)."""
    if kind not in ("tree", "plot"):
        raise ValueError(f"kind must be 'tree' or 'plot', got {kind!r}")
    return {KEY_FONT: f"{font_pt:g}", KEY_DPI: f"{dpi:g}", KEY_KIND: kind}


def stamp(path: str | Path, font_pt: float, dpi: float, kind: str) -> None:
    """Rewrite the PNG at ``path`` with :func:`stamp_info` chunks (pixels unchanged)."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    from ibt.files import atomic_target

    path = Path(path)
    with Image.open(path) as image:
        image.load()
        info = PngInfo()
        for key, value in stamp_info(font_pt, dpi, kind).items():
            info.add_text(key, value)
        with atomic_target(path) as tmp:
            image.save(tmp, format="png", pnginfo=info, optimize=True)


@dataclass(frozen=True)
class Readability:
    """What a committed PNG shows at README width."""

    path: Path
    width_px: int
    height_px: int
    kind: str
    font_pt: float
    dpi: float

    @property
    def aspect(self) -> float:
        return self.width_px / self.height_px

    @property
    def text_pt(self) -> float:
        return text_pt_at_readme_width(self.font_pt, self.dpi, self.width_px)

    def problems(self) -> list[str]:
        """What is wrong with it, each with the number that fails (empty when readable)."""
        out = []
        if self.text_pt < MIN_TEXT_PT - 1e-9:
            out.append(f"{self.path}: smallest text {self.text_pt:.1f} pt at README width "
                       f"({README_WIDTH_PX} px), below {MIN_TEXT_PT:g} pt")
        if self.kind == "tree" and self.aspect > MAX_ASPECT + 1e-9:
            out.append(f"{self.path}: tree drawing {self.width_px}x{self.height_px} px has "
                       f"aspect {self.aspect:.2f}, above {MAX_ASPECT:g}:1")
        return out


def measure(path: str | Path) -> Readability:
    """Read a PNG's size and stamp; ``ValueError`` naming the fix when it has no stamp."""
    from PIL import Image

    path = Path(path)
    with Image.open(path) as image:
        width, height = image.size
        text = dict(getattr(image, "text", {}) or {})
    if KEY_FONT not in text or KEY_DPI not in text:
        raise ValueError(f"{path} carries no readability stamp; write it with "
                         "ibt.report.plots.save_figure or ibt.export.pictures.save_drawing")
    return Readability(path, width, height, text.get(KEY_KIND, "plot"), float(text[KEY_FONT]),
                       float(text[KEY_DPI]))
