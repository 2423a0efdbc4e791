"""Assessment report of a recorded trainer session: one self-contained HTML page.

Sections come from :data:`thrsim.report.document.SECTIONS`, one provider per mode group of the
session file (navigation now; reaming adds its provider when its mode exists), each with its
plots and its scoring criteria; the summary adds up every section's criteria.
"""

from thrsim.report.document import Criterion, Section, build_report

__all__ = ["Criterion", "Section", "build_report"]
