"""An embedded bench built from one configuration and the daemon's instrument from another (issue 13).

A test makes the daemon's nominal values differ from the bench's truths this way: e.g. the bench's
monitor MZI at 201 ns while the daemon's configuration says 200 ns. The composition root builds it
(``lidard.instrument.compose.open_split_bench``); scenes are set through the instrument's sim hooks,
as the daemon does (``set_scene`` with the scene file's structure).
"""

from __future__ import annotations

from lidard.instrument.compose import open_split_bench as open_split

__all__ = ["open_split"]
