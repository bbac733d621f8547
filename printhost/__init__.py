"""printhost: a print server for 3D printers, CNC routers and lasers."""

#: The release, as pyproject.toml names it; the API dialects report it.
__version__ = "0.1.0"
