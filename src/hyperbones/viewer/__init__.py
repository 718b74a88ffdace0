"""The browser viewer (``hyperbones view``)."""
