"""Typed errors of the byte-channel layer shared by every serial-style driver.

Errors name the device and, where there is one, the command that was in flight, so a log line
or an API error body says *which* instrument stopped answering to *what*.
"""

from __future__ import annotations


class TransportError(Exception):
    """The byte channel itself failed: cannot open, write, or read (names device and URL)."""

    def __init__(self, device: str, message: str, *, url: str | None = None) -> None:
        self.device = device
        self.url = url
        where = f" ({url})" if url else ""
        super().__init__(f"{device}{where}: {message}")


class DeviceTimeout(TransportError):
    """The device did not answer ``command`` within the timeout, after all retries."""

    def __init__(
        self,
        device: str,
        command: str,
        *,
        timeout_s: float | None = None,
        attempts: int | None = None,
        url: str | None = None,
    ) -> None:
        self.command = command
        self.timeout_s = timeout_s
        self.attempts = attempts
        detail = f"no answer to {command}"
        if attempts is not None:
            detail += f" after {attempts} attempt{'s' if attempts != 1 else ''}"
        if timeout_s is not None:
            detail += f" (timeout {timeout_s:g} s each)"
        super().__init__(device, detail, url=url)
