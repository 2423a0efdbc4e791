"""Assessment report of a recorded trainer session: one self-contained HTML page.

Sections come from the providers in :mod:`thrsim.report.document`, one per mode group of the
session file (:mod:`thrsim.report.navigation`, :mod:`thrsim.report.reaming`), each with its
plots and its scoring criteria; the summary adds up every section's criteria.
"""

from thrsim.report.document import Assessment, Criterion, Section, assess, build_report

__all__ = ["Assessment", "Criterion", "Section", "assess", "build_report"]
