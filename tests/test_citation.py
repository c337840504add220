"""The citation and archive metadata: ``CITATION.cff`` is valid Citation File Format 1.2.0, and
its version and licence agree with ``pyproject.toml``, ``LICENSE``, ``.zenodo.json`` and
``ibt.__version__``.

The schema is the Citation File Format's own (``tests/fixtures/cff-1.2.0.schema.json``, from the
citation-file-format repository at tag 1.2.0, CC-BY-4.0). ``cffconvert --validate`` checks the
same schema, but cffconvert 2.0.0 pins ``jsonschema<4``, which the notebooks' tooling cannot run
with, so the check is done here with the ``jsonschema`` the environment already has.
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import jsonschema
import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
SCHEMA = json.loads((Path(__file__).parent / "fixtures" / "cff-1.2.0.schema.json").read_text())
PAPER_TITLE = ("Imitation-BT: Automating Behavior Tree Generation by Echoing Reinforcement "
               "Learning Agents")
#: what a Zenodo deposit needs from ``.zenodo.json`` (its legacy deposit API's required fields)
ZENODO_REQUIRED = ("title", "upload_type", "description", "creators")


def _citation() -> dict:
    return yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))


def _cff_errors(citation: dict) -> list[str]:
    validator = jsonschema.Draft7Validator(SCHEMA, format_checker=jsonschema.FormatChecker())
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
            for e in validator.iter_errors(citation)]


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_the_citation_file_is_valid_cff_1_2_0():
    assert _cff_errors(_citation()) == []


@pytest.mark.parametrize("break_it", [
    lambda c: c.pop("authors"),
    lambda c: c.__setitem__("cff-version", "1.2"),
    lambda c: c["preferred-citation"].__setitem__("type", "paper"),
    lambda c: c.__setitem__("date-released", "07/12/2026"),
])
def test_a_broken_citation_file_is_rejected(break_it):
    # Expect: the check can fail: a missing field, a wrong version, type or date is named
    citation = copy.deepcopy(_citation())
    break_it(citation)
    assert _cff_errors(citation)


def test_the_preferred_citation_is_the_reproduced_paper():
    paper = _citation()["preferred-citation"]
    assert paper["title"] == PAPER_TITLE
    assert [a["family-names"] for a in paper["authors"]] == ["Bathula", "Parasuraman"]


def test_version_and_licence_agree_everywhere():
    import ibt

    project = _project()
    zenodo = json.loads((ROOT / ".zenodo.json").read_text())
    citation = _citation()
    versions = {"pyproject.toml": project["version"], "CITATION.cff": str(citation["version"]),
                ".zenodo.json": zenodo["version"], "ibt.__version__": ibt.__version__}
    assert len(set(versions.values())) == 1, versions
    licences = {"pyproject.toml": project["license"], "CITATION.cff": citation["license"],
                ".zenodo.json": zenodo["license"]}
    assert set(licences.values()) == {"MIT"}, licences
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")


def test_the_archive_metadata_has_what_a_deposit_needs():
    zenodo = json.loads((ROOT / ".zenodo.json").read_text())
    assert all(zenodo.get(key) for key in ZENODO_REQUIRED), zenodo.keys()
    assert zenodo["upload_type"] == "software"
    assert all(creator.get("name") for creator in zenodo["creators"])
    assert any(PAPER_TITLE in reference for reference in zenodo["references"])


def test_the_readme_shows_how_to_cite():
    readme = (ROOT / "README.md").read_text()
    assert "CITATION.cff" in readme and PAPER_TITLE in readme.replace("\n", " ")
