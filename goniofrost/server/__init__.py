"""The rig as an instrument: ``goniofrost serve`` holds a rig's devices and runs one plan at a time
from a queue kept in SQLite, behind an HTTP JSON API (``api``) beside the monitor's read-only views.

``store`` keeps the queue and the journal of control actions; ``instrument`` drives the held
hardware (its state, the pause gate the engine asks between samples); ``api`` is the Starlette app;
``serve`` opens everything for the command; ``client`` is how another command reaches a server.
"""
