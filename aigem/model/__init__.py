"""The model and its data: the network (network.AiGem), which nodes each encoder layer computes
(plan), the typed Batch (batch), a build's samples as batches (data) and as PyTorch Geometric's
HeteroData (pyg), and the loss (loss).

The lowest wing: it imports only the modules at aigem's top (config), no other wing.
"""
