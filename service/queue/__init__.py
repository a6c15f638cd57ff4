"""Queue backends; :func:`make_backend` picks one from the settings."""

from __future__ import annotations

from service.queue.base import QueueBackend
from service.settings import Settings
from service.store import Store


def make_backend(settings: Settings, store: Store) -> QueueBackend:
    """The backend named by ``PBA_QUEUE``."""
    if settings.queue == "local":
        from service.queue.local import LocalPoolBackend

        return LocalPoolBackend(settings, store)
    if settings.queue == "celery":
        from service.queue.celery_backend import CeleryBackend

        return CeleryBackend(settings, store)
    raise NotImplementedError(f"unknown queue backend {settings.queue!r} (local or celery)")


__all__ = ["QueueBackend", "make_backend"]
