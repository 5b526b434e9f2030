"""Self-contained HTML reports: headings, text, tables and matplotlib figures embedded as PNG.

One file, no external resources, so a report can be mailed or archived as it is.
"""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["Report", "error_histograms"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{border-bottom:2px solid #246;padding-bottom:.3em}h2{color:#246;margin-top:1.6em}
table{border-collapse:collapse;margin:.8em 0;font-size:.92em}th,td{border:1px solid #ccc;padding:.3em .6em;text-align:right}
th{background:#eef2f7}td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#555}
.meta{color:#666;font-size:.85em}pre{background:#f6f8fa;padding:.6em;overflow-x:auto;font-size:.85em}
"""


@dataclass
class Report:
    """An HTML report assembled piece by piece; :meth:`write` produces one self-contained file."""

    title: str
    parts: list[str] = field(default_factory=list)
    n_figures: int = 0

    def heading(self, text: str, level: int = 2) -> Report:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def text(self, text: str) -> Report:
        self.parts.append(f"<p>{html.escape(text)}</p>")
        return self

    def pre(self, text: str) -> Report:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def table(self, header: list[str], rows: list[list], caption: str | None = None) -> Report:
        """A table; floats are shown with 4 significant digits."""

        def cell(v):
            if isinstance(v, float):
                return f"{v:.4g}"
            return html.escape(str(v))

        h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
        body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self.parts.append(f"<table>{cap}<thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>")
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
        return (
            "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1><p class='meta'>hykin {__version__}, generated {stamp}</p>"
            + "\n".join(self.parts)
            + "</body></html>"
        )

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.html(), encoding="utf-8")
        return path


def error_histograms(before_mm, after_mm, before_deg=None, after_deg=None, labels=("before", "after")):
    """Figure with position (and orientation) error distributions before vs after (paper Fig. 4/8 style)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    ncol = 2 if before_deg is not None else 1
    fig, axes = plt.subplots(1, ncol, figsize=(5.2 * ncol, 3.6), squeeze=False)
    for ax, b, a, unit in (
        (axes[0, 0], before_mm, after_mm, "position error [mm]"),
        *(((axes[0, 1], before_deg, after_deg, "orientation error [deg]"),) if ncol == 2 else ()),
    ):
        b, a = np.asarray(b), np.asarray(a)
        # Log-spaced bins: before and after differ by orders of magnitude.
        lo = max(min(b.min(), a.min()), 1e-15)
        hi = max(b.max(), a.max())
        bins = np.geomspace(lo, hi * 1.01, 50)
        ax.hist(b, bins=bins, alpha=0.6, label=labels[0])
        ax.hist(a, bins=bins, alpha=0.6, label=labels[1])
        ax.set_xscale("log")
        ax.set_xlabel(unit)
        ax.set_ylabel("samples")
        ax.legend()
    fig.tight_layout()
    return fig
