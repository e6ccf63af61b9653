"""Benchmarks: each prints both sides of a comparison in one run and their ratio (results: ``io.BENCH_RESULT``)."""
