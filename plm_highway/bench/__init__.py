"""Benchmarks: each prints both sides of a comparison in one run and their ratio."""

from plm_highway.io import file_kind

BENCH_RESULT = file_kind("bench-result", "a benchmark result JSON file")
