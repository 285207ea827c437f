"""Typed errors shared by the host side (daemon, CLI, configuration)."""


class LidardError(Exception):
    """Base class for errors lidard reports to users as one clear line."""


class ConfigError(LidardError):
    """A configuration, profile or scene file is invalid; the message names file, key and rule."""


class UnknownScan(LidardError):
    """No scan with that id (the job queue, the store's services and the API share it)."""
