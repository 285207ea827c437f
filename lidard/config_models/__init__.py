"""The pydantic models of lidard.config, one module per part of the file format.

Import them from :mod:`lidard.config`, which re-exports every model; this package only splits the rooms.
"""
