"""Shared test options and fixtures."""

from __future__ import annotations


def pytest_addoption(parser) -> None:
    parser.addoption("--digests", action="store_true", default=False,
                     help="print the results digests of tests/test_results_digest.py (to re-baseline them)")
