"""Evaluation of a run: scoring its models and constant velocity on a split, the results
and their published rows, predictions of single samples and followed targets.
"""
