"""Evaluation: a run scored beside constant velocity (evaluate), its sums in one pass over a
split (scoring), the results and the published rows (results), a run's predictions for chosen
samples (prediction) and the target a scene picture follows (followed).

It imports training (the static batches scoring runs on), runs, model and aigem's top.
"""
