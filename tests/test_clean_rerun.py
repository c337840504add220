"""A rerun of ``make figures`` leaves the checkout clean: no git commit in what notebooks and
result manifests record, PDFs without creation dates, the timing out of the README, and the
unread cache entries as one line."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

import ibt
from ibt.cache.store import load_or_compute


def test_notebook_provenance_names_no_git_commit():
    from ibt.runs.steps import provenance

    facts = provenance()
    assert "git_sha" not in facts and "python" in facts and "numpy" in facts


def test_result_manifests_name_no_git_commit(tmp_path):
    from ibt.runs.grid import write_results

    cfg = ibt.config("smoke", data_dir=tmp_path)
    target = write_results(cfg, pd.DataFrame({"wall_seconds": [1.0]}), "demo", cells=1)
    manifest = json.loads(target.with_suffix(".manifest.json").read_text())
    assert "git_sha" not in manifest and manifest["cells"] == 1


def test_composed_pdfs_are_the_same_bytes_every_time(tmp_path):
    from PIL import Image

    from ibt.export.pictures import compose
    from ibt.export.readable import stamp

    panel = tmp_path / "panel.png"
    Image.new("RGB", (40, 30), "white").save(panel)
    stamp(panel, 10.0, 110.0, "plot")
    first = compose([panel], tmp_path / "a" / "fig", formats=("pdf",))[0].read_bytes()
    second = compose([panel], tmp_path / "b" / "fig", formats=("pdf",))[0].read_bytes()
    assert first == second and b"CreationDate" not in first


def test_matplotlib_pdfs_carry_no_creation_date(tmp_path):
    import matplotlib.pyplot as plt

    from ibt.report.plots import save_figure

    fig, ax = plt.subplots()
    ax.plot(np.arange(3))
    pdf = save_figure(fig, tmp_path / "f", formats=("pdf",))[0].read_bytes()
    plt.close(fig)
    assert b"CreationDate" not in pdf


def test_unread_cache_entries_are_one_line_with_the_command_that_lists_them(tmp_path, capsys):
    from ibt.cache import admin as cache_admin

    cache = tmp_path / "cache"
    for i in range(3):
        load_or_compute("tree-eval", {"i": i}, lambda: {"x": 1}, cache_dir=cache, codec="json")
    reads = tmp_path / "reads"
    reads.mkdir()
    argv = ["stale", "--cache-dir", str(cache), "--reads", str(reads)]
    assert cache_admin.main([*argv, "--count"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and "3 unread" in lines[0]
    assert f"python -m ibt.cache.admin {' '.join(argv)}" in lines[0]
    assert cache_admin.main(argv) == 0
    assert len(capsys.readouterr().out.strip().splitlines()) == 4  # the list itself


def test_nothing_unread_is_no_line_at_all(tmp_path, capsys):
    # Expect: a clone whose every cache entry was read prints nothing at the end of make figures
    from ibt.cache import admin as cache_admin
    from ibt.cache.store import cache_key

    cache = tmp_path / "cache"
    load_or_compute("tree-eval", {"i": 0}, lambda: {"x": 1}, cache_dir=cache, codec="json")
    reads = tmp_path / "reads"
    reads.mkdir()
    (reads / "reads-1.txt").write_text(f"tree-eval/{cache_key('tree-eval', {'i': 0})}\n")
    assert cache_admin.main(["stale", "--cache-dir", str(cache), "--reads", str(reads),
                             "--count"]) == 0
    assert capsys.readouterr().out == ""
