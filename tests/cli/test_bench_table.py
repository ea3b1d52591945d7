"""The performance figures live in one table of docs/performance.md that the benchmark
writes (``bench --table``; issue 25): the table from a run's figures, put between the page's
markers without touching the rest of the page."""

import os

import pytest

from octoprint_kincomp.tools.benchmark import (
    TABLE_BEGIN,
    TABLE_END,
    TABLE_FILE,
    markdown_table,
    replace_table,
)


def _hook(p50, p99):
    return {"p50_us": p50, "p99_us": p99}


def _engine(copy, comp, p50):
    return {
        "copy_s": copy,
        "compensate_s": comp,
        "ratio": comp / copy,
        "arc_copy_s": copy,
        "arc_compensate_s": 2 * comp,
        "arc_ratio": 2 * comp / copy,
        "rss": {"growth_mb": 4.0},
        "hook": {
            "process": _hook(p50, 2 * p50),
            "process_arc": _hook(3 * p50, 4 * p50),
            "handle": _hook(p50 + 0.5, 3.0),
            "handle_arc": _hook(2.5, 4.0),
            "takeup_share": 0.3,
        },
    }


RES = {
    "lines": 1000,
    "file_mb": 0.04,
    "verify": {"verified_lines": 1234},
    "engines": {"compiled": _engine(0.16, 0.38, 0.65), "python": _engine(0.18, 0.80, 30.0)},
    "a1": {
        "growth": {
            "200 arcs kept": {
                "lines": 1.024,
                "bytes": 1.037,
                "arcs_kept": 3862,
                "arcs_split": 89,
                "arcs_linearised": 0,
                "max_dev_um": 0.53,
            }
        },
        "serial": {
            "arcs kept": {
                "needed_mean": 37.0,
                "needed_p99": 104,
                "needed_peak": 288,
                "mean_line_bytes": 30.0,
                "capacity": {"115200": 305.0},
            }
        },
    },
}


def test_the_table_holds_every_figure_of_the_run():
    table = markdown_table(RES, "2026-11-27")
    rows = [r for r in table.splitlines() if r.startswith("| ")]
    assert rows[0] == "| measure | target | compiled kernel | pure Python |"
    assert all(r.count(" | ") == 3 for r in rows), rows  # four columns in every row
    assert "0.38 s vs 0.16 s = **2.4x**" in table and "0.80 s vs 0.18 s = **4.4x**" in table
    assert "p50 **0.65 us**, p99 1.30 us" in table and "p50 **30.00 us**" in table
    assert "A1 file at 200 um/m XY squareness, arcs kept" in table and "1.037x" in table
    assert "37 mean, 104 p99 second, 288 busiest; carried 305 at 115200 baud" in table
    assert "1,234 output lines" in table and "2026-11-27" in table


def test_the_table_replaces_only_what_is_between_the_markers(tmp_path):
    page = tmp_path / "performance.md"
    page.write_text(f"# Performance\n\nbefore\n\n{TABLE_BEGIN}\nold table\n{TABLE_END}\n\nafter\n")
    replace_table(str(page), "| new | table |")
    text = page.read_text()
    assert "old table" not in text and "| new | table |" in text
    assert text.startswith("# Performance\n\nbefore\n\n") and text.endswith("\n\nafter\n")
    with pytest.raises(ValueError):
        replace_table(_no_markers(tmp_path), "x")


def _no_markers(tmp_path):
    p = tmp_path / "plain.md"
    p.write_text("# no table here\n")
    return str(p)


def test_the_docs_page_has_one_table_between_the_markers():
    with open(TABLE_FILE, encoding="utf-8") as f:
        text = f.read()
    assert text.count(TABLE_BEGIN) == 1 and text.count(TABLE_END) == 1
    inside = text.split(TABLE_BEGIN)[1].split(TABLE_END)[0]
    outside = text.replace(inside, "")
    assert inside.count("| measure | target |") == 1
    assert "| measure" not in outside  # the figures are in that one table only
    assert os.path.basename(TABLE_FILE) == "performance.md"


@pytest.mark.slow
def test_a_run_of_one_engine_measures_and_verifies_that_engine_only(tmp_path):
    """``bench --engine NAME`` (a refresh of the compiled figures without the pure-Python
    path's half hour): that engine alone is verified against the reference path and timed."""
    from octoprint_kincomp.engines import select
    from octoprint_kincomp.tools import benchmark

    name = select.available()
    res = benchmark.run(3000, workdir=str(tmp_path), quick=True, only=name)
    assert list(res["engines"]) == [name] and res["verify"]["engines"] == [name]
    assert res["verify"]["identical"] and res["verify"]["verified_lines"] > 3000
    assert res["engines"][name]["hook"]["process"]["lines"] > 100
    table = markdown_table(res, "2026-11-28")
    assert table.count(" | ") > 10 and ("pure Python" in table) == (name == "python")
    with pytest.raises(ValueError):
        benchmark.engines("numpy")
