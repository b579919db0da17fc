"""Benchmarks: each performance claim of the documentation (docs/) has a script here that runs baseline and ours
side by side in one run and prints the ratio (medians; machines are shared and noisy)."""
