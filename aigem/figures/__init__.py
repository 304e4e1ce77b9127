"""The figures of an evaluation: its errors by horizon and region, the pictures of
`aigem evaluate --plots`, the published rows as markers.
"""
