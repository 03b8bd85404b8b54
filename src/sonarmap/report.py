"""Self-contained HTML reports: figures embedded as PNG data, tables, parameters."""

from __future__ import annotations

import base64
import html
import json
import platform
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .files import atomic_write_text
from .version import __version__

__all__ = ["Report"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1400px; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #f2f2f2; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
pre { background: #f7f7f7; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
.note { color: #555; }
"""

# Marks the body once every figure has loaded and decoded, so that a headless browser
# (the tests) can tell a complete report from a broken one.
_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute('data-figures', String(imgs.length));
  document.body.setAttribute('data-figures-loaded', String(ok));
  document.body.setAttribute('data-tables', String(document.getElementsByTagName('table').length));
});
"""


def _cell(v: Any) -> str:
    if v is None:
        return "-"  # not measured for this row (e.g. outliers of a method without them)
    if isinstance(v, float):
        return "-" if v != v else f"{v:.3f}"  # NaN prints as a dash
    return html.escape(str(v))


@dataclass
class Report:
    """An HTML report built section by section, written as one file."""

    title: str
    parts: list[str] = field(default_factory=list)
    n_figures: int = 0

    def heading(self, text: str) -> None:
        self.parts.append(f"<h2>{html.escape(text)}</h2>")

    def text(self, text: str) -> None:
        self.parts.append(f"<p class='note'>{html.escape(text)}</p>")

    def figure(self, png: Path, caption: str) -> None:
        data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
        self.n_figures += 1
        self.parts.append(
            f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
            f"<figcaption>Figure {self.n_figures}. {html.escape(caption)}</figcaption></figure>"
        )

    def table(self, rows: Sequence[Mapping[str, Any]], caption: str = "") -> None:
        if not rows:
            return
        cols = list(rows[0])
        head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
        body = "".join(
            "<tr>" + "".join(f"<td>{_cell(r.get(c))}</td>" for c in cols) + "</tr>" for r in rows
        )
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self.parts.append(
            f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
        )

    def parameters(self, params: Mapping[str, Any]) -> None:
        self.heading("Parameters")
        self.parts.append(f"<pre>{html.escape(json.dumps(params, indent=2, default=str))}</pre>")

    def write(self, path: Path) -> Path:
        stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        foot = (
            f"<p class='note'>sonarmap {__version__}, Python {platform.python_version()}, "
            f"{html.escape(platform.platform())}; generated {stamp}.</p>"
        )
        doc = (
            f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style>"
            f"<script>{_SCRIPT}</script></head><body><h1>{html.escape(self.title)}</h1>"
            + "".join(self.parts)
            + foot
            + "</body></html>"
        )
        atomic_write_text(path, doc)
        return path
