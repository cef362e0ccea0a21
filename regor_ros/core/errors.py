"""The two errors the core raises, both with a message a user can act on."""


class ConfigError(ValueError):
    """A configuration value is impossible; the message names the field."""


class RegistrationError(ValueError):
    """The input cannot be registered; the message says why and what to change."""
