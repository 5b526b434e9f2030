"""The HTML report document: headings, paragraphs, a summary box, tables and matplotlib figures
embedded as PNG, in ONE self-contained file (no external URL) laid out for the screen and for A4 print.

This module only assembles a document; what goes into hykin's model report is decided by
:mod:`.report_build` (the one builder that ``hykin report``, ``hykin evaluate --report`` and
``hykin demo`` share). The figures live in :mod:`.report_figures`.
"""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from .report_figures import error_histograms

__all__ = ["Report", "deg", "error_histograms", "fmt", "mm"]

# Screen: at most 1100 px wide. Print: A4 with 14 mm margins (182 mm of text width); tables shrink
# their font and wrap long cells, figures scale to the width and never split across pages.
_CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;max-width:1100px;margin:1.5em auto;
padding:0 1em;color:#222;line-height:1.4;overflow-wrap:break-word}
h1{border-bottom:2px solid #246;padding-bottom:.3em;font-size:1.6em}h2{color:#246;margin-top:1.5em;font-size:1.25em}
h3{font-size:1.05em;margin-bottom:.3em}
.summary{background:#f3f7fb;border-left:4px solid #246;padding:.5em 1em;margin:1em 0}
.summary li{margin:.25em 0}
.note{color:#555;font-size:.9em}
.meta{color:#666;font-size:.85em}
.tablewrap{max-width:100%;overflow-x:auto}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em;max-width:100%}
caption{text-align:left;font-size:.95em;color:#444;padding:.2em 0;caption-side:top}
th,td{border:1px solid #ccc;padding:.2em .45em;text-align:right;vertical-align:top;white-space:nowrap}
th{background:#eef2f7}td:first-child,th:first-child{text-align:left}
td.text,th.text{text-align:left;white-space:normal}
tr.held td{color:#777}tr.warn td{background:#fff6e0}
figure{margin:.8em 0;break-inside:avoid;page-break-inside:avoid}
figure img{max-width:100%;height:auto;border:1px solid #ddd;display:block}
figcaption{font-size:.88em;color:#555;margin-top:.2em}
pre{background:#f6f8fa;padding:.6em;white-space:pre-wrap;font-size:.82em}
@page{size:A4;margin:14mm}
@media print{body{max-width:none;margin:0;padding:0;font-size:10pt}h1{font-size:16pt}h2{font-size:12.5pt;
break-after:avoid;page-break-after:avoid}table{font-size:7.5pt;break-inside:auto}tr{break-inside:avoid}
.tablewrap{overflow:visible}.summary{break-inside:avoid}}
"""


def fmt(v, digits: int = 4) -> str:
    """A cell's text: floats with ``digits`` significant digits (``-`` for None / NaN), others as str."""
    if v is None:
        return "–"
    if isinstance(v, float) or type(v).__name__.startswith("float"):
        v = float(v)
        if v != v:
            return "–"
        return f"{v:.{digits}g}"
    return str(v)


def mm(v: float, zeros: bool = False) -> str:
    """A length in mm for a sentence: as µm below 0.01 mm, "< 1 nm" below a nanometre (rounding level;
    tables keep the exact figure); 3 significant digits. ``zeros``: keep trailing zeros (4.9952 ->
    "5.00 mm", not "5 mm": a figure that reads as exact where it is rounded)."""
    g = lambda x: f"{x:#.3g}".rstrip(".") if zeros else f"{x:.3g}"
    if abs(v) >= 0.01 or v == 0:
        return f"{g(v)} mm"
    return f"{g(v * 1e3)} µm" if abs(v) >= 1e-6 else "< 1 nm"


def deg(v: float) -> str:
    """An angle in degrees for a sentence (3 significant digits), "< 1e-9°" below that (rounding level)."""
    return f"{v:.3g}°" if abs(v) >= 1e-9 or v == 0 else "< 1e-9°"


@dataclass
class Report:
    """An HTML report assembled piece by piece; :meth:`write` produces one self-contained file."""

    title: str
    parts: list[str] = field(default_factory=list)
    n_figures: int = 0
    subtitle: str = ""

    def heading(self, text: str, level: int = 2) -> Report:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def text(self, text: str, cls: str | None = None) -> Report:
        c = f" class='{cls}'" if cls else ""
        self.parts.append(f"<p{c}>{html.escape(text)}</p>")
        return self

    def note(self, text: str) -> Report:
        """A small grey paragraph (how a figure was computed, what a table leaves out)."""
        return self.text(text, "note")

    def bullets(self, items: list[str], cls: str | None = None) -> Report:
        c = f" class='{cls}'" if cls else ""
        lis = "".join(f"<li>{html.escape(s)}</li>" for s in items)
        self.parts.append(f"<ul{c}>{lis}</ul>")
        return self

    def summary(self, items: list[str]) -> Report:
        """The boxed summary in words at the top of the report."""
        lis = "".join(f"<li>{html.escape(s)}</li>" for s in items)
        self.parts.append(f"<div class='summary'><strong>Summary</strong><ul>{lis}</ul></div>")
        return self

    def pre(self, text: str) -> Report:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def table(self, header: list[str], rows: list[list], caption: str | None = None, *, text_cols=1,
              row_classes: list[str] | None = None, digits: int = 4) -> Report:
        """A table; floats with ``digits`` significant digits. Text columns (left-aligned, wrapped): the
        first ``text_cols`` columns (an int) or the column indices ``text_cols`` (a set); the others are
        numbers (right-aligned, never wrapped). ``row_classes``: a CSS class per row ("held": greyed)."""
        texts = set(range(text_cols)) if isinstance(text_cols, int) else set(text_cols)
        tc = lambda k: " class='text'" if k in texts else ""
        h = "".join(f"<th{tc(k)}>{html.escape(str(c))}</th>" for k, c in enumerate(header))
        body = []
        for i, r in enumerate(rows):
            cls = f" class='{row_classes[i]}'" if row_classes and row_classes[i] else ""
            body.append(f"<tr{cls}>" + "".join(f"<td{tc(k)}>{html.escape(fmt(v, digits))}</td>" for k, v in enumerate(r)) + "</tr>")
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self.parts.append(f"<div class='tablewrap'><table>{cap}<thead><tr>{h}</tr></thead><tbody>{''.join(body)}</tbody></table></div>")
        return self

    def figure(self, fig, caption: str = "") -> Report:
        """Embed a matplotlib figure as a base64 PNG and close it."""
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
        plt.close(fig)
        data = base64.b64encode(buf.getvalue()).decode("ascii")
        self.n_figures += 1
        alt = html.escape(caption or f"figure {self.n_figures}")
        self.parts.append(
            f'<figure><img alt="{alt}" src="data:image/png;base64,{data}"/>'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
        return self

    def html(self) -> str:
        from .. import __version__

        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        sub = f"<p class='meta'>{html.escape(self.subtitle)}</p>" if self.subtitle else ""
        return (
            "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>{sub}<p class='meta'>written by hykin {__version__}, {stamp}</p>"
            + "\n".join(self.parts)
            + "</body></html>"
        )

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.html(), encoding="utf-8")
        return path
