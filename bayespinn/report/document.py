"""A report as a list of blocks, so report.md and report.html are two renderings of one content.

Text in blocks may use three inline marks, understood by both renderers: **bold**, `code` and
[a link](relative/path) (relative paths only: reports never point outside their folder).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Heading:
    text: str
    level: int = 2


@dataclass(frozen=True)
class Paragraph:
    text: str


@dataclass(frozen=True)
class Alert:
    """A statement that must not be missed (identifiability, failed convergence, disagreement)."""

    text: str
    kind: str = "warning"  # 'warning' or 'info'


@dataclass(frozen=True)
class Table:
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""


@dataclass(frozen=True)
class Figure:
    """A PNG in the report folder (`path` relative to it)."""

    title: str
    path: str
    caption: str = ""


@dataclass(frozen=True)
class Code:
    text: str
    language: str = ""


@dataclass(frozen=True)
class BulletList:
    items: tuple[str, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Headline:
    """The answer in a few sentences, first in every report: `lead` (EI with its interval, or the misfit
    with its advice), then labelled statements (`items`: (label, text) pairs such as ("Fit", ...)).
    `kind`: 'ok' when nothing is wrong, 'warning' when something is."""

    lead: str
    items: tuple[tuple[str, str], ...] = ()
    kind: str = "ok"


Block = Heading | Paragraph | Alert | Table | Figure | Code | BulletList | Headline


def table(header, rows, caption: str = "") -> Table:
    """A Table from any iterables of cells (converted to str)."""
    return Table(
        tuple(str(h) for h in header), tuple(tuple(str(c) for c in r) for r in rows), caption
    )
