"""Re-render the committed study pages from their JSON with today's code, running nothing.

Each page shows, beside its figures, the commit, date and machine of the runs that computed them: a
page rendered after a change of the code still shows the figures that code's predecessors measured, and
says so by their commits. `tests/test_records.py` fails while a committed page differs from what this
script would write.

    python studies/render.py --out reports/paper
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # the study modules import each other by name, as scripts do
    sys.path.insert(0, str(HERE))

import common as c  # noqa: E402

log = logging.getLogger("studies.render")

#: pages gathered from the study files under <out>/<name>
GATHERED = ("family", "girders", "girder_pinns", "fitcheck")


def module_of(name: str) -> str:
    """The study script that renders page `name`: coverage-<girder>-<case> pages are coverage's."""
    return "coverage" if name.startswith("coverage") else name


def pages(out: Path) -> list[str]:
    """The table pages under <out>: coverage (and one per other girder or case) and the paper's tables."""
    cov = sorted(p.stem for p in out.glob("coverage*.json"))
    return cov + [t for t in ("table4", "table5", "table6") if (out / f"{t}.json").exists()]


def page_text(name: str, out: Path) -> str | None:
    """The markdown today's code renders for <out>/<name>.json (None when the JSON is not there)."""
    from bayespinn.report.markdown import render_markdown

    mod = importlib.import_module(module_of(name))
    if name in GATHERED:  # gathered from the study files under <out>/<name>
        page = mod.gather(out)
        return render_markdown(mod.blocks(page)) if page["studies"] else None
    path = out / f"{name}.json"
    if not path.exists():
        return None
    doc = c.load_table(path, mod.SCHEMA)
    if module_of(name) == "coverage":
        mod.refresh(doc, out, figure=False)
    return render_markdown(mod.blocks(doc))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--out", default="reports/paper", help="folder of the study pages (default reports/paper)"
    )
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    c.setup_logging(False)
    out = Path(args.out)
    for name in pages(out):
        path = out / f"{name}.json"
        mod = importlib.import_module(module_of(name))
        doc = c.load_table(path, mod.SCHEMA)
        if module_of(name) == "coverage":
            mod.write_page(doc, out)
        else:
            c.write_markdown(out / f"{name}.md", mod.blocks(doc))
        log.info("rendered %s", out / f"{name}.md")
    for name in GATHERED:
        mod = importlib.import_module(name)
        if mod.gather(out)["studies"]:
            mod.write_page(out)
    return 0


if __name__ == "__main__":
    c.entry(main)
