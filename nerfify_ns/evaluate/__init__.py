"""Stage 4: training runs, metrics and visual feedback."""
