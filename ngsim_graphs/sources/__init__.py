"""Data sources: each dataset's files to the tracks table, the seam every later stage reads.

A source (`contract.Source`) finds its files, reads each into rows labelled by recording, and
turns one recording's rows into its tracks table. After the seam nothing knows which dataset the
rows came from; the build's manifest records it (`dataset`). The contract, in full, is in
`contract.py`, and docs/conventions.md says it too ("The tracks table").
"""
