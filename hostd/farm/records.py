"""A farm job's entry in the jobs bucket (JSON), its states, and the message that offers it."""

from __future__ import annotations

import json
import secrets
from dataclasses import asdict, dataclass, field, replace
from typing import Any

# a job's states: waiting in the queue, taken by a printer (its lease held by
# heartbeats), printed, failed (with the reason), interrupted (its printer's daemon
# stopped mid-print and reported it after a restart: the part is on that bed)
STATES = ("waiting", "taken", "printed", "failed", "interrupted")
# states in which a printer holds the job
HELD = ("taken", "interrupted")


def new_job_id() -> str:
    """A fresh job id, ``fj-`` and ten hex digits (a key, a file stem, a subject token)."""
    return f"fj-{secrets.token_hex(5)}"


def is_job_id(text: str) -> bool:
    """True for a text :func:`new_job_id` could have made."""
    return (len(text) == 13 and text.startswith("fj-")
            and all(c in "0123456789abcdef" for c in text[3:]))


@dataclass(frozen=True)
class Entry:
    """One job as the jobs bucket holds it (key: the job id).

    ``generation`` numbers the offers of the job (the stream's messages): 1 at submit,
    one more at each requeue; a message of an older generation is stale. ``token``
    marks one take, so that a take whose answer was lost can tell it won. ``beat`` is
    the holder's last heartbeat (Unix time), ``lease_s`` how long it may fall silent.
    """

    id: str
    name: str
    model: str  # the object's name in the models store (the model's SHA-256)
    size: int
    settings: dict[str, Any] = field(default_factory=dict)
    needs: dict[str, Any] = field(default_factory=dict)
    state: str = "waiting"
    printer: str | None = None
    reason: str | None = None
    submitted: float = 0.0
    updated: float = 0.0
    generation: int = 1
    token: str | None = None
    beat: float = 0.0
    lease_s: float = 0.0
    layer: int = -1  # the last layer the holder reported complete

    def to_bytes(self) -> bytes:
        """The bucket's value."""
        return json.dumps(asdict(self), sort_keys=True).encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> Entry:
        """The inverse of :meth:`to_bytes` (unknown fields ignored)."""
        values = json.loads(data)
        known = {name for name in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in values.items() if k in known})

    def but(self, **changes: Any) -> Entry:
        """A copy with ``changes``."""
        return replace(self, **changes)


def offer(job_id: str, generation: int) -> bytes:
    """The stream message that offers a job to the printers."""
    return json.dumps({"id": job_id, "generation": generation}).encode()


def read_offer(data: bytes) -> tuple[str, int]:
    """(job id, generation) of an offer; ValueError when it is not one."""
    values = json.loads(data)
    if not isinstance(values, dict):
        raise ValueError("not a farm offer")
    job_id, generation = values.get("id"), values.get("generation")
    if not isinstance(job_id, str) or not isinstance(generation, int):
        raise ValueError("not a farm offer")
    return job_id, generation
