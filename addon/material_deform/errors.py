"""The add-on's one error type (its own module so that every layer, the bridge included, can
raise it without importing the layers above)."""


class BindError(Exception):
    """Bad input or stale bind; the message is meant for the user."""
