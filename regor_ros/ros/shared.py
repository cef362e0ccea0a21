"""What the localizer's parts share (ros/localizer.py): one lock, which the executor's callbacks,
the worker and the services all go through, the settings in force, and whether the node takes
inputs or is stopping."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..core import RegorConfig
    from .parameters import NodeSettings


@dataclass
class Shared:
    """The state every part reads under ``lock``; a parameter change replaces config and settings
    whole (Localizer.change), so a job keeps the pair it started with."""

    config: RegorConfig
    settings: NodeSettings
    lock: threading.Condition = field(default_factory=threading.Condition)
    active: bool = False     # taking inputs and registering
    stopping: bool = False   # the node's publishers are going away: report nothing

    def snapshot(self) -> tuple[RegorConfig, NodeSettings]:
        """The configuration and settings in force now (a registration keeps the ones it started with)."""
        with self.lock:
            return self.config, self.settings
