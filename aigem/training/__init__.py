"""Training: a fit (fit), its epochs, the one training step (trainers), the ensemble of
members, the static batches on the device (engine, resident, loading, capacity) and the
learning-rate schedule.
"""
