"""Live views of a running scan: the points measured so far (for the web viewer's incremental fetch)."""
