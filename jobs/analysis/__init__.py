"""What printhost knows about a G-code file: time, filament, layers, pictures.

Sans-IO: `Analyser` takes bytes and returns an `Analysis`; reading the stored file,
storing the result and running it in Celery live in `jobs.analysing` and
`jobs.tasks`.
"""
