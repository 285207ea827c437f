"""How long the suite's waits wait before calling something hung.

A test waits for a condition (a daemon answering /health, a scan or a stream ending, a reply, a
subprocess exiting) and goes on the moment it holds; these deadlines only bound a wait that never
ends. They are never the measured quantity, so a generous deadline costs nothing when things work,
and it keeps the suite green on a loaded machine: with 8 busy processes beside ``pytest -n 2`` on 2
cores, every step takes about five times as long as on the idle machine (README, "Tests").
"""

from __future__ import annotations

WAIT_S = 300.0
"""A job, a scan, a stream or a subprocess to end (idle: well under a minute)."""

STARTUP_S = 300.0
"""A daemon process from its start to /health answering (idle: ~5 s; the import of the DSP and the
child bench's start dominate)."""

HTTP_S = 120.0
"""One HTTP request to a daemon that is scanning (idle: milliseconds)."""

REPLY_S = 10.0
"""One reply of a simulated device over a socket or pty when nothing is lost on purpose (idle: ~0.1 ms).
A driver retries after its timeout, so a test that counts retries or requests needs a timeout no late
reply reaches."""
