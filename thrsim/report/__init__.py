"""Assessment report of a recorded trainer session: one self-contained HTML page.

Sections come from the providers in :mod:`thrsim.report.document`, one per mode group of the
session file (:mod:`thrsim.report.navigation`, :mod:`thrsim.report.reaming`), each with its
plots and its scoring criteria; the summary adds up every criterion. :func:`build_assessment` gives
the same assessment as data (``thrsim report --json``).
"""

from thrsim.report.document import Assessment, Criterion, Section, build_assessment, build_report

__all__ = ["Assessment", "Criterion", "Section", "build_assessment", "build_report"]
