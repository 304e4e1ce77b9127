"""Training: `fit` (fit), its epochs (epochs), the one training step and validation (trainers),
several models stacked as one (ensemble), the static batches on the device (loading, resident,
capacity, engine) and the learning rate (schedule).

It imports the runs and model wings and aigem's top, never evaluation, figures or the paper.
"""
