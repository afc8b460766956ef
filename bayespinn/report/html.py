"""report.html: one self-contained file. Images are embedded as base64 data URIs, the style sheet is
inline, and there is no script and no external URL at all, so the file opens the same offline, in a
mail attachment or in an archive years later."""

from __future__ import annotations

import base64
import html
import logging
import re
from pathlib import Path

from .document import Alert, Block, BulletList, Code, Figure, Heading, Headline, Paragraph, Table

log = logging.getLogger(__name__)

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 0 auto;
       max-width: 72rem; padding: 1.5rem 2rem 4rem; color: #1d1d1f; line-height: 1.45; }
h1 { font-size: 1.6rem; border-bottom: 2px solid #334; padding-bottom: .3rem; }
h2 { font-size: 1.25rem; margin-top: 2rem; border-bottom: 1px solid #ccd; padding-bottom: .2rem; }
h3 { font-size: 1.05rem; margin-top: 1.4rem; }
table { border-collapse: collapse; margin: .6rem 0 1rem; font-size: .9rem; }
th, td { border: 1px solid #c8c8d0; padding: .25rem .55rem; text-align: left; vertical-align: top; }
th { background: #eef0f5; }
tr:nth-child(even) td { background: #fafafc; }
caption { caption-side: bottom; text-align: left; font-size: .85rem; color: #555; padding-top: .3rem; }
code, pre { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: .85rem; }
pre { background: #f5f5f7; border: 1px solid #ddd; padding: .6rem; overflow-x: auto; }
.alert { border-left: 6px solid #c0392b; background: #fdecea; padding: .6rem .9rem; margin: .8rem 0;
         font-weight: 600; }
.alert.info { border-left-color: #2c6fbb; background: #eaf2fb; font-weight: normal; }
figure { margin: 1rem 0 1.6rem; }
figure img { max-width: 100%; height: auto; border: 1px solid #e2e2e8; }
figcaption { font-size: .88rem; color: #444; margin-top: .3rem; }
.headline { border: 1px solid #b9c7dc; border-left: 8px solid #2e7d32; background: #f3f8f3;
            padding: .9rem 1.2rem; margin: 1rem 0 1.4rem; border-radius: 4px; }
.headline.warning { border-left-color: #c0392b; background: #fdf1ef; border-color: #e3b9b2; }
.headline .lead { font-size: 1.3rem; margin: 0 0 .6rem; line-height: 1.35; }
.headline .row { display: flex; gap: .8rem; margin: .3rem 0; font-size: 1rem; }
.headline .label { flex: 0 0 8.5rem; font-weight: 600; color: #334; }
.missing { color: #8a5a00; font-style: italic; }
"""

_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_BOLD = re.compile(r"\*\*(.+?)\*\*")
_CODE = re.compile(r"`([^`]+)`")
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:|^//")


def inline(text: str) -> str:
    """Escape text and turn the document's inline marks into HTML; links are kept only when relative."""
    out, pos = [], 0
    for m in _CODE.finditer(text):
        out.append(_marks(text[pos : m.start()]))
        out.append(f"<code>{html.escape(m.group(1))}</code>")
        pos = m.end()
    out.append(_marks(text[pos:]))
    return "".join(out)


def _marks(text: str) -> str:
    s = html.escape(text, quote=False)

    def link(m: re.Match) -> str:
        label, href = m.group(1), html.unescape(m.group(2))
        if _SCHEME.match(href):  # never point outside the report folder
            return label
        return f'<a href="{html.escape(href, quote=True)}">{label}</a>'

    s = _LINK.sub(link, s)
    return _BOLD.sub(r"<strong>\1</strong>", s)


def data_uri(path: Path) -> str:
    """The PNG at `path` as a base64 data URI."""
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def render_html(blocks: list[Block], folder: str | Path, title: str) -> str:
    """The blocks as one HTML page; figures are read from `folder` and embedded."""
    folder = Path(folder)
    body = []
    for b in blocks:
        if isinstance(b, Heading):
            lv = min(max(b.level, 1), 6)
            body.append(f"<h{lv}>{inline(b.text)}</h{lv}>")
        elif isinstance(b, Paragraph):
            body.append(f"<p>{inline(b.text)}</p>")
        elif isinstance(b, Headline):
            items = "".join(
                f'<div class="row"><span class="label">{inline(label)}</span>'
                f"<span>{inline(text)}</span></div>"
                for label, text in b.items
            )
            body.append(
                f'<section class="headline {html.escape(b.kind)}" aria-label="the answer">'
                f'<p class="lead">{inline(b.lead)}</p>{items}</section>'
            )
        elif isinstance(b, Alert):
            cls = "alert info" if b.kind == "info" else "alert"
            body.append(f'<div class="{cls}" role="note">{inline(b.text)}</div>')
        elif isinstance(b, Table):
            body.append(_table(b))
        elif isinstance(b, Figure):
            body.append(_figure(b, folder))
        elif isinstance(b, Code):
            body.append(f"<pre><code>{html.escape(b.text)}</code></pre>")
        elif isinstance(b, BulletList):
            body.append("<ul>" + "".join(f"<li>{inline(i)}</li>" for i in b.items) + "</ul>")
        else:  # pragma: no cover - the Block union is closed
            raise TypeError(f"unknown report block {type(b).__name__}")
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{html.escape(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )


def _table(t: Table) -> str:
    head = "".join(f"<th>{inline(h)}</th>" for h in t.header)
    rows = "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>" for r in t.rows)
    cap = f"<caption>{inline(t.caption)}</caption>" if t.caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def _figure(f: Figure, folder: Path) -> str:
    p = folder / f.path
    cap = f"<figcaption>{inline(f.caption)}</figcaption>" if f.caption else ""
    try:
        uri = data_uri(p)
    except OSError as exc:
        log.warning("warning: figure %s not embedded in report.html: %s", f.path, exc)
        return f'<p class="missing">Figure "{html.escape(f.title)}" is missing ({html.escape(f.path)}).</p>'
    alt = html.escape(f.title, quote=True)
    return f'<figure><h3>{inline(f.title)}</h3><img alt="{alt}" src="{uri}">{cap}</figure>'
