"""printhost: a print server for 3D printers, CNC routers and lasers."""
