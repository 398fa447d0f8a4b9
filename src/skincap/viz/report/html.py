"""A self-contained HTML report: sections of text, tables and PNG figures (embedded).

The page needs no network and no other file: figures are embedded as base64 data
URIs, so ``report.html`` can be mailed or attached as one file.
"""

from __future__ import annotations

import base64
import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincap.io._common import atomic_output

__all__ = ["Section", "write_html_report", "format_value"]

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2em auto;
       max-width: 1100px; color: #222; line-height: 1.45; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f3f3f0; }
td:first-child, th:first-child { text-align: left; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.88em; color: #555; }
.frames { display: flex; flex-wrap: wrap; gap: 0.6em; }
.frames figure { flex: 1 1 45%; max-width: 49%; margin: 0; }
code, pre { background: #f5f5f2; padding: 0.1em 0.3em; border-radius: 3px; }
pre { padding: 0.6em; overflow-x: auto; }
.met { color: #1a7a2a; font-weight: 600; } .missed { color: #b0201a; font-weight: 600; }
p.note { color: #555; font-size: 0.92em; }
"""


def format_value(value: Any, digits: int = 4) -> str:
    """A table cell: floats to ``digits`` significant digits, None as an en dash."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


@dataclass
class Section:
    """One section of the report: a title, then paragraphs, tables and figures in order.

    Build it with :meth:`text`, :meth:`table`, :meth:`figure`, :meth:`figures` and
    :meth:`code`; each returns the section so calls chain.
    """

    title: str
    parts: list[str] = field(default_factory=list)

    def text(self, paragraph: str, *, note: bool = False) -> Section:
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(paragraph)}</p>")
        return self

    def table(self, header: list[str], rows: list[list[Any]]) -> Section:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>" for row in rows
        )
        self.parts.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
        return self

    def figure(self, png: str | os.PathLike[str], caption: str) -> Section:
        self.parts.append(_figure(Path(png), caption))
        return self

    def figures(self, pngs: list[tuple[str | os.PathLike[str], str]]) -> Section:
        inner = "".join(_figure(Path(p), c) for p, c in pngs)
        self.parts.append(f'<div class="frames">{inner}</div>')
        return self

    def code(self, text: str) -> Section:
        self.parts.append(f"<pre><code>{html.escape(text)}</code></pre>")
        return self

    def render(self) -> str:
        return f"<section><h2>{html.escape(self.title)}</h2>{''.join(self.parts)}</section>"


def _cell(value: Any) -> str:
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], bool):
        text, met = value
        cls = "met" if met else "missed"
        return f'<span class="{cls}">{html.escape(format_value(text))}</span>'
    return html.escape(format_value(value))


def _figure(png: Path, caption: str) -> str:
    data = base64.b64encode(png.read_bytes()).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def write_html_report(
    path: str | os.PathLike[str],
    title: str,
    intro: str,
    sections: list[Section],
    *,
    force: bool = False,
) -> Path:
    """Write the report atomically and return its path.

    Parameters
    ----------
    path : path-like
        The ``.html`` file.
    title, intro : str
        Page heading and the paragraph under it (plain text, escaped).
    sections : list of Section
    force : bool
        Replace an existing file.
    """
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><p>{html.escape(intro)}</p>"
        + "".join(s.render() for s in sections)
        + "</body></html>\n"
    )
    out = Path(path)
    with atomic_output(out, force=force) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return out
