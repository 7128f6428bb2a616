"""The survey report: `write_report(work)` writes WORK/outputs/report.html, one self-contained page (the
floor as inline SVG, a section per room with its previews, height histogram, figures and automatic
choices, the rooms that failed, accuracy against truth, and the run: stage timings, configuration
differences from the defaults, versions), read from the work dir without recomputing anything
(`gather`)."""

from tasks.report.page import write_report

__all__ = ["write_report"]
