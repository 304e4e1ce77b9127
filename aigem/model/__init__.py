"""The model and its data: the network (AiGem), the plan of a graph's edges, the typed
Batch, the dataset over a build, PyTorch Geometric's view of it, and the loss.
"""
