"""scripts/bench_report.py: the headless Chromium it times runs with the flags this machine needs."""
from __future__ import annotations

import pytest

from conftest import load_script

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def bench_report():
    return load_script("bench_report")


def test_chromium_runs_headless_without_quic_or_background_network(bench_report, tmp_path):
    page = tmp_path / "r.html"
    argv = bench_report.chromium_argv("chromium", page, tmp_path / "profile", tmp_path / "shot.png")
    assert argv[0] == "chromium" and argv[-1] == page.as_uri()
    needed = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
              "--disable-background-networking", "--disable-component-update", "--disable-sync"]
    assert [f for f in needed if f not in argv] == []
    assert f"--user-data-dir={tmp_path / 'profile'}" in argv and f"--screenshot={tmp_path / 'shot.png'}" in argv
    assert len(argv) == 1 + len(needed) + 4
