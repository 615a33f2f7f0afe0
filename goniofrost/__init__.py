"""goniofrost: the control application of a FROST-BRDF gonioreflectometer."""

__version__ = "0.1.0"
