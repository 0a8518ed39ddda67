"""``ptrack report FOLDER --publish NAME``: the report and its figures copied into the site,
the image links pointing at the copies (mkdocs --strict refuses a link outside docs/)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ptrack_gym.errors import InvalidConfigError
from train.evaluation.publish import publish_report


def _folder(tmp_path: Path, text: str) -> Path:
    folder = tmp_path / "results" / "main"
    folder.mkdir(parents=True)
    (folder / "report.md").write_text(text)
    for figure in ("aggregate.png", "robustness_path_dist_rms.png", "example_x.png"):
        (folder / figure).write_bytes(figure.encode())
    return folder


def test_the_report_and_its_figures_land_in_the_site_with_links_to_the_copies(tmp_path):
    folder = _folder(tmp_path, "# Verdict\n\n![aggregate](aggregate.png)\n\ntext (a.png) b\n")
    docs = tmp_path / "docs"
    docs.mkdir()
    written = publish_report(folder, "main", docs)
    report = docs / "results" / "main_report.md"
    assert written[0] == report
    assert report.read_text() == (
        "# Verdict\n\n![aggregate](../figures/main_aggregate.png)\n\ntext (a.png) b\n"
    )
    copies = {p.name: p.read_bytes() for p in written[1:]}
    assert copies == {
        "main_aggregate.png": b"aggregate.png",
        "main_robustness_path_dist_rms.png": b"robustness_path_dist_rms.png",
    }  # the linked figure and the robustness curves; not every png of the folder
    for link in ("../figures/main_aggregate.png",):
        assert (report.parent / link).resolve().exists()


def test_bad_publish_requests_are_refused_before_anything_is_written(tmp_path):
    docs = tmp_path / "docs"
    docs.mkdir()
    folder = _folder(tmp_path, "![gone](missing.png)\n")
    with pytest.raises(InvalidConfigError, match=r"links missing\.png"):
        publish_report(folder, "main", docs)
    with pytest.raises(InvalidConfigError, match="lower-case letters"):
        publish_report(folder, "../main", docs)
    with pytest.raises(InvalidConfigError, match="not a folder"):
        publish_report(folder, "main", tmp_path / "nowhere")
    (folder / "report.md").unlink()
    with pytest.raises(InvalidConfigError, match="nothing to publish"):
        publish_report(folder, "main", docs)
    assert not any(docs.iterdir())
