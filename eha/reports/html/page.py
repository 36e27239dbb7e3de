"""The HTML of the report: one page, plotly's JavaScript embedded once, figures as JSON.

:class:`Page` hands out element ids and renders the pieces: figures (``<div class="plot">``
with the figure as a JSON ``<script>``), a figure with a selector (several figures, one shown),
and sortable, filterable tables (plain HTML; each cell carries its raw value in ``data-v`` for
sorting and for the tests). The CSS and the small script of the page are package data
(``eha/reports/html/assets``); plotly's bundle comes from the plotly package itself.
"""

from __future__ import annotations

import html
import json
import math
from dataclasses import dataclass
from importlib import resources
from typing import Any, Callable, Mapping, Sequence

from eha.reports.html.figures import figure_json, script_json, template_json

#: The page allows no request: scripts and styles are inline, images data URLs only.
CSP = ("default-src 'none'; script-src 'unsafe-inline'; "
       "style-src 'unsafe-inline'; img-src data: blob:; font-src data:")


def esc(text: Any) -> str:
    """HTML-escaped text."""
    return html.escape(str(text), quote=True)


def asset(name: str) -> str:
    """Text of a file of ``eha/reports/html/assets`` (package data)."""
    return resources.files("eha.reports.html").joinpath("assets", name).read_text("utf-8")


def plotly_js() -> str:
    """plotly.js (minified) as shipped in the plotly package, safe inside ``<script>``."""
    from plotly.offline import get_plotlyjs

    return get_plotlyjs().replace("</script", "<\\/script")


@dataclass
class Column:
    """A table column: ``key`` of the row dicts (its value is the cell's raw ``data-v``),
    header text, how the value is shown (``fmt``, or the text of another key ``show``), and
    whether it is left-aligned text."""

    key: str
    header: str
    fmt: Callable[[Any], str] | None = None
    text: bool = False
    show: str | None = None


def fmt_num(digits: int = 4, scale: float = 1.0) -> Callable[[Any], str]:
    """A formatter of numbers with ``digits`` significant digits after ``scale``, without an
    exponent from 1e-3 to 1e6 (one format down a column); ``-`` for None/NaN."""
    from eha.models.units import plain

    def f(v: Any) -> str:
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return "-"
        return plain(scale * float(v), digits)
    return f


def fmt_int(v: Any) -> str:
    """A whole number (cycles, counts); ``-`` for None/NaN."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{float(v):.0f}"


#: Tags of status words (CSS class): bad, warn, good.
TAGS = {"end of life": "bad", "beyond limit": "bad", "degraded": "bad", "unexplained": "bad",
        "failed": "bad", "attention": "warn", "interval reaches limit": "warn",
        "flagged": "warn", "tentative": "warn", "above noise": "warn", "ok": "good", "below limit": "good",
        "healthy": "good", "explained": "good", "done": "good", "yes": "good", "no": "warn"}


def tag(word: Any) -> str:
    """A status word as a coloured tag."""
    if word is None:
        return "-"
    return f'<span class="tag {TAGS.get(str(word), "none")}">{esc(word)}</span>'


def _raw(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, (int, float)):
        return repr(float(v))
    try:                       # numpy scalars
        return repr(float(v))
    except (TypeError, ValueError):
        return str(v)


class Page:
    """Collects the sections of one report and renders the page."""

    def __init__(self, title: str, subtitle: str):
        self.title, self.subtitle = title, subtitle
        self.sections: list[tuple[str, str, str]] = []
        self._n = 0
        self.figures = 0

    def _id(self, prefix: str) -> str:
        self._n += 1
        return f"{prefix}{self._n}"

    def plot(self, fig: Mapping[str, Any]) -> str:
        """A figure, drawn when the page loads."""
        pid = self._id("plot")
        self.figures += 1
        return (f'<div class="plot" id="{pid}" data-fig="{pid}-data"></div>'
                f'<script type="application/json" id="{pid}-data">{figure_json(fig)}</script>')

    def choice(self, label: str, figs: Mapping[str, Mapping[str, Any]],
               selected: str | None = None) -> tuple[str, str]:
        """Several figures in one place and a selector of which one is shown; returns the HTML
        and the plot's id (a table whose rows name the keys can drive it)."""
        pid = self._id("plot")
        self.figures += 1
        keys = list(figs)
        first = selected if selected in figs else keys[0]
        options = "".join(f'<option value="{esc(k)}"{" selected" if k == first else ""}>'
                          f'{esc(k)}</option>' for k in keys)
        body = ",".join(f"{script_json(json.dumps(str(k)))}:{figure_json(f)}"
                        for k, f in figs.items())
        return (f'<label class="choice" for="{pid}-select">{esc(label)}</label>'
                f'<select class="choice" id="{pid}-select" data-plot="{pid}">{options}</select>'
                f'<div class="plot" id="{pid}"></div>'
                f'<script type="application/json" id="{pid}-data">{{{body}}}</script>', pid)

    def table(self, columns: Sequence[Column], rows: Sequence[Mapping[str, Any]],
              name: str, filter_box: bool = True, choice: tuple[str, str] | None = None) -> str:
        """A sortable table (click a header), with a filter box; ``choice`` = (plot id, row
        key) makes a click on a row show that row's figure in a selector."""
        tid = self._id("table")
        head = "".join(f"<th>{esc(c.header)}</th>" for c in columns)
        body = []
        for r in rows:
            cells = []
            for c in columns:
                v = r.get(c.key)
                if c.show is not None:
                    shown = esc(r.get(c.show))
                else:
                    shown = c.fmt(v) if c.fmt is not None else ("-" if v is None else esc(v))
                cls = ' class="text"' if c.text else ""
                cells.append(f'<td{cls} data-k="{esc(c.key)}" data-v="{esc(_raw(v))}">'
                             f'{shown}</td>')
            attr = f' data-choice="{esc(r.get(choice[1]))}"' if choice else ""
            body.append(f"<tr{attr}>{''.join(cells)}</tr>")
        target = f' data-choice="{choice[0]}"' if choice else ""
        box = (f'<input class="filter" type="search" data-table="{tid}" '
               f'placeholder="filter rows…" aria-label="filter {esc(name)}">'
               if filter_box else "")
        return (f'{box}<div class="tablewrap"><table class="data" id="{tid}" '
                f'data-name="{esc(name)}"{target}><thead><tr>{head}</tr></thead>'
                f'<tbody>{"".join(body)}</tbody></table></div>')

    def add_section(self, sid: str, title: str, body: str) -> None:
        """Add a section (id, heading, HTML body)."""
        self.sections.append((sid, title, body))

    def render(self, footer: str = "") -> str:
        """The whole page."""
        nav = "".join(f'<a href="#{sid}">{esc(t)}</a>' for sid, t, _ in self.sections)
        secs = "".join(f'<section id="{sid}"><h2>{esc(t)}</h2>{b}</section>'
                       for sid, t, b in self.sections)
        return (
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f'<meta http-equiv="Content-Security-Policy" content="{CSP}">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{esc(self.title)}</title><style>{asset('report.css')}</style>"
            f"<script>{plotly_js()}</script>"
            f'<script type="application/json" id="template">{figure_json(template_json())}'
            "</script></head><body>"
            f"<header><h1>{esc(self.title)}</h1><p>{self.subtitle}</p></header>"
            f"<nav>{nav}</nav><main>{secs}</main><footer>{footer}</footer>"
            f"<script>{asset('report.js')}</script></body></html>\n")
