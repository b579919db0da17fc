"""Benchmarks: each performance claim in the README has a script here that runs baseline and ours
side by side in one run and prints the ratio (medians; machines are shared and noisy)."""
