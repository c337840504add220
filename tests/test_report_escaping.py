"""Text from data is escaped on its way to Markdown: a ``<script>`` (or a ``|``) in a field of
``data/experts/manifest.csv`` or a result's manifest reaches the tables, footnotes and list of
deviations of ``paper/reproduction.md`` as text (:func:`ibt.report.text.md`), not as a live
tag or a cut table row."""

from __future__ import annotations

import json
import re
import shutil

import pandas as pd
from hypothesis import given
from hypothesis import strategies as st

from ibt.paths import DATA_DIR
from ibt.report import markdown, tables
from ibt.report.deviations import deviations_markdown
from ibt.report.text import md, md_url

SCRIPT = "<script>alert('owned')</script>"


def test_a_script_in_the_experts_manifest_reaches_the_report_as_text(tmp_path):
    shutil.copytree(DATA_DIR / "results", tmp_path / "results")
    (tmp_path / "experts").mkdir()
    experts = pd.read_csv(DATA_DIR / "experts" / "manifest.csv")
    experts.loc[0, "status"] = "excluded"
    experts.loc[0, "status_evidence"] = f"{SCRIPT} | [click](javascript:x)"
    experts["net_arch"] = experts["net_arch"].astype(str)
    experts.loc[1, "net_arch"] = SCRIPT
    experts.loc[2, "hyperparams_source"] = SCRIPT
    experts.to_csv(tmp_path / "experts" / "manifest.csv", index=False)
    manifest = tmp_path / "results" / "distillation.manifest.json"
    facts = json.loads(manifest.read_text()) if manifest.exists() else {}
    manifest.write_text(json.dumps({**facts, "machine": SCRIPT}))
    res = markdown.Results(tmp_path)
    text = "\n".join([tables.experts_markdown(res), tables.status_footnotes(res),
                      deviations_markdown(res), tables.timings_markdown(res)])
    assert "<script" not in text and not re.search(r"(?<!\\)\]\(javascript:", text)
    assert "&lt;script&gt;" in text
    rows = [line for line in text.splitlines() if line.startswith("| CartPole-v1 | dqn |")]
    assert rows and all(line.replace("\\|", "").count("|") == 8 for line in rows)


@given(st.text(max_size=40))
def test_md_leaves_no_tag_no_cell_break_and_no_new_line(text):
    out = md(text)
    assert "<" not in out and ">" not in out and "\n" not in out and "\r" not in out
    assert "|" not in out.replace("\\|", "")


def test_md_is_the_identity_on_plain_names():
    for name in ("CartPole-v1", "ppo", "64x64", "zoo:hyperparams/ppo.yml (5e4 steps there)"):
        assert md(name) == name
    assert md_url("data/trees/a b)/x.png") == "data/trees/a%20b%29/x.png"


def test_code_blocks_outlast_backticks_in_names():
    from ibt.pipeline.outputs import fenced

    assert fenced("python -m ibt evaluate bt.json", "bash") == [
        "```bash", "python -m ibt evaluate bt.json", "```"]
    block = fenced("python -m ibt pipeline My```Task-v0 ppo\n``````", "bash")
    fence = block[0].removesuffix("bash")
    assert fence == "`" * 7 and block[-1] == fence
    assert fence not in block[1]  # nothing inside can close it
