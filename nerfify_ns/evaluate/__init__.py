"""Stages 6 to 8 (``train``, ``patches``, the report): training runs, metrics and visual feedback."""
