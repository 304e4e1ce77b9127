"""The paper's experiments and report (`aigem paper`): the work run or reused (experiments), the
fits each part needs at each seed (plan), the folder and paper.json (folder), the runs trained
(training), and report.json, report.md and their figures (report, report_parts, report_cells,
report_text, report_tables, report_plots).

The top wing: it imports every other, and none imports it.
"""
