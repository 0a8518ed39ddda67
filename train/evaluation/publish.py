"""Publish a results folder's generated report into the documentation site.

``ptrack report FOLDER --publish NAME`` rewrites ``FOLDER/report.md`` and then copies it to
``docs/results/NAME_report.md``, and its figures (the images the report links, and the
robustness curves beside it) to ``docs/figures/NAME_<figure>.png``, with the report's image
links rewritten to those copies. The site builds with ``mkdocs --strict``, which refuses a
link to a file outside ``docs/``; a report copied by hand kept a link to the results
folder's own ``aggregate.png``, which is not committed.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from ptrack_gym.errors import InvalidConfigError

#: An image link to a file beside the report: ``![alt](file.png)``.
_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)/\s]+\.png)\)")
_NAME = re.compile(r"[a-z0-9][a-z0-9_]*")


def publish_report(folder: Path, name: str, docs: Path) -> list[Path]:
    """Copy ``folder``'s ``report.md`` and figures into the site under ``docs``; return the
    files written (the report first).

    Args:
        folder: a results folder whose ``report.md`` is written (``ptrack report`` rewrites it
            first).
        name: the published name: ``docs/results/<name>_report.md``,
            ``docs/figures/<name>_<figure>``; lower-case letters, digits and ``_``.
        docs: the site's source folder (``docs/`` of the checkout).

    Raises:
        InvalidConfigError: a bad ``name``, no ``report.md``, or a linked figure missing.
    """
    if not _NAME.fullmatch(name):
        raise InvalidConfigError(
            f"--publish {name!r}: a name of lower-case letters, digits and '_' (e.g. main)"
        )
    if not docs.is_dir():
        raise InvalidConfigError(f"{docs} is not a folder: publish from a checkout of the project")
    report = folder / "report.md"
    if not report.exists():
        raise InvalidConfigError(f"{report} does not exist: nothing to publish")
    text = report.read_text()
    linked = [m.group(2) for m in _IMAGE.finditer(text)]
    missing = [f for f in linked if not (folder / f).exists()]
    if missing:
        raise InvalidConfigError(f"{report} links {', '.join(missing)}, not in {folder}")
    figures = sorted({*linked, *(p.name for p in folder.glob("robustness_*.png"))})
    out_report = docs / "results" / f"{name}_report.md"
    out_report.parent.mkdir(parents=True, exist_ok=True)
    (docs / "figures").mkdir(parents=True, exist_ok=True)
    written = [out_report]
    for figure in figures:
        target = docs / "figures" / f"{name}_{figure}"
        shutil.copyfile(folder / figure, target)
        written.append(target)
    out_report.write_text(
        _IMAGE.sub(lambda m: f"![{m.group(1)}](../figures/{name}_{m.group(2)})", text)
    )
    return written
