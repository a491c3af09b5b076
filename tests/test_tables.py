"""Every table the package prints is drawn by ``rft_mujoco.tables``: the formatter itself, each table
function drawing through it (its output follows the column separator when that changes), and no module
drawing a table by hand (no rules of dashes, no padding, no padded column titles outside it)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rft_mujoco import tables
from rft_mujoco.tables import Columns, table

PACKAGE = Path(tables.__file__).resolve().parent


@pytest.fixture(autouse=True)
def _plain_style(monkeypatch):
    monkeypatch.delenv(tables.STYLE_VARIABLE, raising=False)


def test_table_aligns_columns_under_a_rule():
    text = table(["shape", "elements", "err %"], [["sphere", 412, "1.93"], ["box", 12, "10.50"]])
    assert text.splitlines() == [
        "shape   elements  err %",
        "------  --------  -----",
        "sphere       412   1.93",
        "box           12  10.50",
    ]
    assert table(["a", "b"], [["xyz", "1"]], align="><").splitlines() == ["  a  b", "---  -", "xyz  1"]


def test_columns_print_rows_as_they_come_with_the_tables_layout():
    rows = [["sphere", "412", "1.93"], ["box", "12", "10.50"]]
    whole = table(["shape", "elements", "err %"], rows)
    columns = Columns(["shape", "elements", "err %"], widths=[6, 0, 5])
    assert "\n".join([columns.header(), *(columns.row(r) for r in rows)]) == whole
    assert columns.row(["a much longer name", "1", "2"]).startswith("a much longer name  ")  # widens its line only


def test_markdown_style_for_pasting_into_a_page(monkeypatch):
    monkeypatch.setenv(tables.STYLE_VARIABLE, "markdown")
    assert table(["shape", "|F| N"], [["sphere", "3.5"]]).splitlines() == [
        "| shape  | |F| N |".replace("|F|", "\\|F\\|"),
        "|:-------|------:|",
        "| sphere |   3.5 |",
    ]
    columns = Columns(["a", "b"], widths=[3, 3])
    assert columns.header().splitlines()[1] == "|:----|----:|" and columns.row(["x", "1"]) == "| x   |   1 |"
    monkeypatch.setenv(tables.STYLE_VARIABLE, "html")
    with pytest.raises(ValueError, match="RFT_MUJOCO_TABLES must be one of plain, markdown, got 'html'"):
        table(["a"], [["1"]])


@pytest.mark.parametrize("call, match", [
    (lambda: table(["a", "b"], [["1"]]), "one cell per column"),
    (lambda: table(["a", "b"], [["1", "2"]], align="<"), "one '<'"),
    (lambda: table(["a"], [["1"]], align="|"), "one '<'"),
    (lambda: Columns([]), "at least one column"),
    (lambda: Columns(["a", "b"], widths=[3]), "one width per column"),
    (lambda: Columns(["a", "b"]).row(["1", "2", "3"]), "one cell per column"),
])
def test_bad_tables_say_what_is_wrong(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def _formatters():
    """Each table function of the package with small inputs of its own shape: name -> () -> text."""
    from rft_mujoco.coupling import setup
    from rft_mujoco.studies import anymass, overlap, swim

    out = {
        "overlap.table_lines": lambda: "\n".join(overlap.table_lines([dict(
            case="hinge_0", motion="down", hidden_fraction=0.2, force_ref=[3.0, 4.0, 0.0], error=0.01,
            error_no_cull=0.1, overcount=1.1, area_error=0.002)])),
        "anymass.table": lambda: "\n".join(anymass.table(dict(limits={0.5: 0.1}, rows=[dict(
            density_scale=0.01, timestep_s=0.002, amplitude_rad=0.5, solve="implicit", eta=0.1, error=0.02)]))),
        "swim._table": lambda: "\n".join(swim._table([dict(eta=0.31, wall_s=2.0)], ["eta", "wall_s"], [".3f", ".1f"])),
        "setup.summary_text": lambda: setup.summary_text([dict(
            body="foot", source="collision", area=0.01, culled=0.002, elements=40, smallest=0.02,
            geoms=["foot (sphere)"])], 0.01).rsplit("\n", 1)[0],   # the last line is the total, not the table
    }
    try:
        from rft_mujoco.train import commands, evaluate
    except ImportError:   # the train extra is missing: its tables are checked where it is installed
        return out
    row = dict(policy="trained", ground="sand", command=[0.4, 0.0, 0.0], vx=0.38, yaw=-0.05, falls=0, episodes=3,
               sinkage_m=0.1, trained_on="sand")
    row["return"] = 700.0
    out.update({
        "commands.format_rows": lambda: commands.format_rows([row]),
        "commands.format_gap": lambda: commands.format_gap([row]),
        "evaluate.format_table": lambda: evaluate.format_table(dict(speed_key="x_velocity", policies={"trained": dict(
            return_mean=1399.0, return_std=110.0, length_mean=1000.0, speed_mean=0.3, speed_std=0.15)})),
    })
    return out


FORMATTERS = _formatters()


@pytest.mark.parametrize("name", sorted(FORMATTERS))
def test_every_table_function_draws_through_the_one_module(name, monkeypatch):
    """With the column separator of rft_mujoco.tables changed, every line of each table function's output
    (titles, rule, rows) carries it the same number of times: the function draws nothing itself."""
    plain = FORMATTERS[name]().splitlines()
    monkeypatch.setattr(tables, "GAP", " | ")
    marked = FORMATTERS[name]().splitlines()
    assert len(marked) == len(plain) >= 3, marked                     # titles, rule, at least one row
    counts = {line.count(" | ") for line in marked}
    assert len(counts) == 1 and counts.pop() >= 1, marked             # the same columns on every line
    assert set(marked[1].replace(" | ", "")) == {"-"}, marked          # the rule is the module's


HAND_DRAWN = re.compile(r"""\{'[^']*':[<>^]?\d+s?\}|"-" ?\*|'-' ?\*|\.ljust\(|\.rjust\(""")
"""What a hand-drawn table looks like: a padded column title ({'policy':<8}), a rule of dashes, padding."""


def test_no_module_draws_a_table_by_hand():
    found = [f"{path.relative_to(PACKAGE.parent)}:{i}: {line.strip()}"
             for path in sorted(PACKAGE.rglob("*.py")) if path.name != "tables.py"
             for i, line in enumerate(path.read_text().splitlines(), 1) if HAND_DRAWN.search(line)]
    assert not found, "tables drawn outside rft_mujoco/tables.py:\n" + "\n".join(found)
    assert HAND_DRAWN.search("""f"{'policy':<8} {'return':>8}" """) and HAND_DRAWN.search('"-" * len(head)')
