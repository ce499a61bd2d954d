"""Exceptions whose message is meant for the user: the CLI prints them on one line."""


class SlimsegError(Exception):
    """Base class: bad input a user can fix (the message says how)."""


class ConfigError(SlimsegError, ValueError):
    """A configuration file (recipe, augmentation, ablation, ...) is malformed; the message
    names the file and the field."""
