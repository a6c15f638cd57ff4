"""API keys: generation, hashing, and resolving a request's key to a user.

A key is ``pba_<prefix>_<secret>`` with 256 random bits in the secret; the store keeps only
its SHA-256 (a fast hash is enough for keys of this entropy, unlike passwords) and the public
prefix, used to name a key when revoking it. The key is shown once, by ``pba admin create-key``.
"""

from __future__ import annotations

import hashlib
import secrets

from service.store import Store, UserRecord

LOCAL_USER = "local"


def hash_key(key: str) -> str:
    """SHA-256 hex digest of an API key."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def new_key() -> tuple[str, str]:
    """A fresh key and its public prefix."""
    prefix = secrets.token_hex(4)
    return f"pba_{prefix}_{secrets.token_urlsafe(32)}", prefix


def create_key(
    store: Store,
    user_name: str,
    is_admin: bool | None = None,
    max_queued_jobs: int | None = None,
    max_job_observations: int | None = None,
) -> tuple[str, UserRecord]:
    """Create a user (or update the given fields of an existing one) and give it a new key;
    returns (key, user)."""
    user = store.create_user(user_name, is_admin, max_queued_jobs, max_job_observations)
    key, prefix = new_key()
    store.add_api_key(user.id, hash_key(key), prefix)
    return key, user


def user_for_key(store: Store, key: str) -> UserRecord | None:
    """The user of an API key, or None when the key is unknown."""
    if not key or len(key) > 200:
        return None
    return store.user_for_key_hash(hash_key(key))


def local_user(store: Store) -> UserRecord:
    """The single user of local mode (an admin named ``local``)."""
    return store.create_user(LOCAL_USER, is_admin=True)
