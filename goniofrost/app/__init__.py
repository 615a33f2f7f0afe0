"""The application layer: the command line, its commands and the demo; the only layer that knows every package."""
