"""make bench's sweep (lensfit.fitting.sweep): each lens's row comes from its own
`lensfit fit` process, CPU-limited; refusals and unfinished fits are rows with their
reason, not failures of the sweep. The fits themselves belong to `make bench`."""

from __future__ import annotations

from lensfit.pipeline import sweep


def test_a_refused_lens_is_a_row_with_its_reason():
    """2002 (a rear attachment) is refused up front: exit 2 and the one line, in well
    under the limit."""
    row = sweep.fit_one({"name": "2002", "lens": "2002", "coating": "file"}, cpu_limit=60)
    assert row["status"] == "refused" and row["exit"] == 2
    assert "no real image" in row["reason"] and "2002" in row["reason"]
    assert row["cpu_seconds"] < 30


def test_a_fit_past_its_cpu_limit_is_unfinished():
    """RLIMIT_CPU stops the fit (0001 needs far more than 3 CPU-s): 'unfinished', with
    the limit named."""
    row = sweep.fit_one({"name": "0001", "lens": "0001", "coating": "file"}, cpu_limit=3)
    assert row["status"] == "unfinished", row
    assert row["reason"] == "not finished within 3 CPU-s"
    assert 2.0 <= row["cpu_seconds"] <= 10.0


def test_jobs_cover_lensdb_both_coatings_and_the_fixtures():
    jobs = sweep.jobs([], ("file", "none"))
    ids = {j["name"] for j in jobs if "import" not in j}
    assert len(ids) == 20 and {"0001", "2004"} <= ids
    assert sum(j["coating"] == "none" for j in jobs) == 20
    imported = [j for j in jobs if "import" in j]
    assert len(imported) == len(sweep.IMPORTED)
    assert all((sweep.FIXTURES / rel).is_file() for rel in sweep.IMPORTED)


def test_markdown_counts_within_target_and_refusals():
    rows = [
        {"lens": "a", "coating": "file", "status": "fitted", "cpu_seconds": 50.0,
         "wall_seconds": 51.0, "worst": 0.005, "where": "f/2 axis 450 nm", "table_kb": 80.0,
         "terms": 5000, "seconds": {"sampling": 10.0, "fitting": 5.0, "psf_check": 30.0,
                                    "rest": 6.0}},
        {"lens": "b", "coating": "file", "status": "fitted", "cpu_seconds": 150.0,
         "wall_seconds": 151.0, "worst": 0.005, "where": "x", "table_kb": 1.0, "terms": 1},
        {"lens": "c", "coating": "file", "status": "refused", "reason": "no | image"},
        {"lens": "d", "coating": "none", "status": "unfinished", "cpu_seconds": 300.0,
         "wall_seconds": 300.0, "reason": "not finished within 300 CPU-s"},
    ]
    text = sweep.markdown(rows, 300, 1)
    assert "1 of 4 within 1% and 120 CPU-s; 1 refused, 1 not finished within 300 CPU-s" in text
    assert "| 10 / 5 / 30 / 6 |" in text
    assert "no / image" in text  # a | in a reason does not break the table
