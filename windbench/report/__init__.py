"""Comparison reports: run and sweep folders -> combined dataset -> figures -> report."""
