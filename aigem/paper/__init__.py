"""The paper's experiments and report (`aigem paper`): the plan of builds, fits and seeds,
its folder, the training and evaluation of every run, and report.json, report.md and figures/.
"""
