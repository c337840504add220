"""``python -m ibt.check_claims`` (``make verify``): the claims table is current, checks pass, and a
planted wrong number fails on its row."""

from __future__ import annotations

import pandas as pd
import pytest

from ibt import check_claims


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    return check_claims.claims_table()


def test_the_committed_claims_table_is_the_generated_one(table):
    # Expect: paper/claims.csv is exactly what the committed results give (never hand-kept)
    assert table.to_csv(index=False) == check_claims.CLAIMS_FILE.read_text()


def test_every_headline_bt_and_every_claim_has_rows(table):
    headline = pd.read_csv(check_claims.ROOT / check_claims.HEADLINE)
    for name in headline.name.unique():
        for stat in ("nodes", "mean_return", "std_return", "retention_norm"):
            assert f"headline.{name}.{stat}" in set(table.id)
    from ibt.report import claims

    verdicts = table[table.source == "verdict"]
    assert {i for i in verdicts.id if i.count(".") == 1} == {
        f"verdict.{fn.__name__.removeprefix('claim_')}" for fn in claims.CLAIMS}
    assert (table.tolerance >= 0).all() and table.command.str.startswith("python -m ibt").all()


@pytest.mark.parametrize(("text", "expected"), [
    ("LunarLander-v3: median 1.7x, range -2.5 to 3", ["1.7", "-2.5", "3"]),
    ("path 0-4-8-15 over 1,000 episodes, 95 % CI", ["0", "4", "8", "15", "1,000", "95"]),
    ("exponential p=0.1 beats x2 and v1", ["0.1"]),
])
def test_numbers_are_read_as_printed(text, expected):
    assert check_claims.numbers(text) == expected


def test_smoke_checks_a_few_rows_and_passes(capsys):
    assert check_claims.main(["--smoke"]) == 0
    out = capsys.readouterr().out
    assert "OK    headline." in out and "OK    verdict." in out and "DIFF" not in out


def _planted(tmp_path, row_id: str, value: str):
    table = pd.read_csv(check_claims.CLAIMS_FILE, dtype=str, keep_default_na=False)
    assert row_id in set(table.id)
    table.loc[table.id == row_id, "value"] = value
    path = tmp_path / "claims.csv"
    path.write_text(table.to_csv(index=False))
    return path


@pytest.mark.parametrize(("row_id", "value", "only"), [
    ("verdict.nodes.1", "9.99", "verdict.nodes"),  # a number of the node-count evidence
    ("verdict.nodes", "reproduced", "verdict.nodes"),  # the verdict itself
])
def test_a_planted_wrong_number_fails_on_its_row(tmp_path, capsys, row_id, value, only):
    path = _planted(tmp_path, row_id, value)
    assert check_claims.main(["--claims", str(path), "--only", only]) == 1
    out = capsys.readouterr().out
    assert f"DIFF  {row_id}: the table says {value}" in out
    assert out.count("DIFF") == 1 and "row: " in out


def test_a_planted_wrong_headline_number_fails_in_the_smoke_form(tmp_path, capsys):
    rows = check_claims.smoke_rows(check_claims.read_claims(check_claims.CLAIMS_FILE))
    nodes = next(r for r in rows if r.id.endswith(".nodes"))
    path = _planted(tmp_path, nodes.id, str(int(nodes.value) + 1))
    assert check_claims.main(["--claims", str(path), "--smoke", "--only", nodes.id]) == 1
    assert f"DIFF  {nodes.id}" in capsys.readouterr().out


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    assert check_claims.main(["--claims", str(tmp_path / "absent.csv")]) == 2
    assert check_claims.main(["--only", "no.such.row"]) == 2
    bad = tmp_path / "bad.csv"
    bad.write_text("id,value\nx,1\n")
    assert check_claims.main(["--claims", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("error: ") for line in err)
