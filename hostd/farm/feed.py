"""The farm queue's rows for a viewer (the fleet view): one connection, kept, read on demand."""

from __future__ import annotations

from typing import Any

from hostd.config import FarmConfig
from hostd.farm.queue import FarmQueue


class FarmFeed:
    """``await feed()``: the queue as ``hostd farm list --json`` gives it (connects on first
    use, and again after a failure)."""

    def __init__(self, config: FarmConfig) -> None:
        self.config = config
        self.queue: FarmQueue | None = None

    async def __call__(self) -> list[dict[str, Any]]:
        if self.queue is None:
            self.queue = await FarmQueue.open(self.config, "hostd-fleet-view")
        try:
            return [row.to_dict() for row in await self.queue.listing()]
        except Exception:
            queue, self.queue = self.queue, None
            await queue.close()
            raise
