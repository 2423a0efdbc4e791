"""Assessment report of a recorded trainer session: one self-contained HTML page.

Each mode of :mod:`thrsim.app.modes` gives its part of the report for its group of the session
file (:mod:`thrsim.report.navigation`, :mod:`thrsim.report.reaming`, built of the blocks in
:mod:`thrsim.report.parts`), with its plots and its scoring criteria; :mod:`thrsim.report.document`
assembles them, and its summary adds up every criterion. :func:`build_assessment` gives the same
assessment as data (``thrsim report --json``).
"""

from thrsim.report.document import Assessment, build_assessment, build_report
from thrsim.report.parts import Criterion, Section

__all__ = ["Assessment", "Criterion", "Section", "build_assessment", "build_report"]
