"""The version of the distribution (ngsim-graphs, which holds both packages), written once.

pyproject.toml reads it from here (`[tool.setuptools.dynamic]`, a literal that setuptools reads
without importing the package), `ngsim_graphs` and `aigem` re-export it, and a module that records
it (a manifest's software, an export's header) imports it from here, never from a package's
`__init__`.
"""

__version__ = "0.1.0"
