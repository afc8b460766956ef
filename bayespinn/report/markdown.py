"""report.md: the credible-interval report a person reads (display units: GN m^2, mm, kN m, µε).

`render_markdown` turns document blocks into Markdown; figures are referenced by their PNG file names
in the same folder, so report.md and report.html show the same figures.
"""

from __future__ import annotations

from ..config import Config
from .document import Alert, Block, BulletList, Code, Figure, Heading, Headline, Paragraph, Table
from .units import fmt_EI, sigma_unit  # noqa: F401  (re-exported for older imports)


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def render_markdown(blocks: list[Block]) -> str:
    """The blocks as Markdown text."""
    lines: list[str] = []
    for b in blocks:
        if isinstance(b, Heading):
            lines += ["#" * min(max(b.level, 1), 6) + " " + b.text, ""]
        elif isinstance(b, Paragraph):
            lines += [b.text, ""]
        elif isinstance(b, Headline):
            lines += [b.lead, ""]
            lines += [f"- **{label}:** {text}" for label, text in b.items] + [""]
        elif isinstance(b, Alert):
            lead = "**Note.**" if b.kind == "info" else "**Warning.**"
            lines += [f"> {lead} {b.text}", ""]
        elif isinstance(b, Table):
            lines.append("| " + " | ".join(_cell(h) for h in b.header) + " |")
            lines.append("|" + "---|" * len(b.header))
            lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in b.rows]
            lines.append("")
            if b.caption:
                lines += [f"*{b.caption}*", ""]
        elif isinstance(b, Figure):
            lines += [f"### {b.title}", "", f"![{b.title}]({b.path})", ""]
            if b.caption:
                lines += [b.caption, ""]
        elif isinstance(b, Code):
            lines += [f"```{b.language}", b.text, "```", ""]
        elif isinstance(b, BulletList):
            lines += [f"- {i}" for i in b.items] + [""]
        else:  # pragma: no cover - the Block union is closed
            raise TypeError(f"unknown report block {type(b).__name__}")
    return "\n".join(lines).rstrip() + "\n"


def markdown(result, cfg: Config, figures=(), figure_notes=(), table5s=(), table5_notes=()) -> str:
    """The run report as Markdown (figures: `figures.FigureFile`s already written)."""
    from .content import run_document

    return render_markdown(run_document(result, cfg, figures, figure_notes, table5s, table5_notes))
