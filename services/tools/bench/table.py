"""Moved to ``shared.evaluation.table``; re-exported here so the bench's imports keep
working."""

from shared.evaluation.table import PAPER_TABLE_I, format_paper_table, format_table

__all__ = ["PAPER_TABLE_I", "format_paper_table", "format_table"]
