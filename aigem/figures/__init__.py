"""The figures of an evaluation: its errors by horizon and region (plots), what `aigem evaluate
--plots` writes (pictures), and the published rows as hollow markers (published).

It imports evaluation and the wings below it; a run's curves.png is the runs wing's.
"""
