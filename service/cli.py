"""``pba serve`` and ``pba admin ...`` (registered into the ``pba`` command by solver.cli).

``pba worker`` (a distributed worker) is added by the Celery backend (issue 8) next to these.
"""

from __future__ import annotations

import argparse
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the service's subcommands."""
    serve = subparsers.add_parser("serve", help="run the HTTP server (OGC API - Processes)")
    serve.add_argument("--host", default=None, help="bind address (default PBA_HOST or 127.0.0.1)")
    serve.add_argument("--port", type=int, default=None, help="port (default PBA_PORT or 8000)")
    serve.add_argument(
        "--workers", type=int, default=None, help="local worker processes (PBA_WORKERS)"
    )
    serve.add_argument("--data-dir", default=None, help="data directory (PBA_DATA_DIR)")
    serve.set_defaults(func=cmd_serve)

    admin = subparsers.add_parser("admin", help="administration: API keys")
    admin_sub = admin.add_subparsers(dest="admin_command", metavar="ACTION")
    ck = admin_sub.add_parser("create-key", help="create a user's API key (printed once)")
    ck.add_argument("--user", required=True, help="user name (created if new)")
    ck.add_argument(
        "--admin",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the user sees every job (--no-admin revokes; default: unchanged, new users not)",
    )
    ck.add_argument("--max-queued-jobs", type=int, default=None, help="per-user limit")
    ck.add_argument("--max-job-observations", type=int, default=None, help="per-user limit")
    ck.set_defaults(func=cmd_create_key)
    rk = admin_sub.add_parser("revoke-key", help="revoke a key by its prefix (pba_<prefix>_...)")
    rk.add_argument("prefix")
    rk.set_defaults(func=cmd_revoke_key)
    admin.set_defaults(func=lambda args: admin.print_help() or 2)


def _settings(args: argparse.Namespace):  # noqa: ANN202 - Settings, imported lazily
    from service.settings import Settings

    overrides = {}
    for name in ("host", "port", "workers", "data_dir"):
        value = getattr(args, name, None)
        if value is not None:
            overrides[name] = value
    return Settings(**overrides)


def cmd_serve(args: argparse.Namespace) -> int:
    """Run uvicorn with the app and the local worker pool."""
    import uvicorn

    from service.app import create_app
    from service.logs import configure_logging

    settings = _settings(args)
    configure_logging(settings.log_level, settings.log_format)
    if settings.auth_required and not settings.require_api_keys:
        print(
            f"binding to {settings.host}: API keys are required (pba admin create-key)",
            file=sys.stderr,
        )
    app = create_app(settings)
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_config=None,
        access_log=False,
        timeout_graceful_shutdown=max(5, int(settings.shutdown_grace_s) + 5),
    )
    return 0


def cmd_create_key(args: argparse.Namespace) -> int:
    """Create a key and print it (only its hash is stored)."""
    from service.auth import create_key
    from service.store import open_store

    settings = _settings(args)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = open_store(settings.resolved_database_url)
    try:
        key, user = create_key(
            store, args.user, args.admin, args.max_queued_jobs, args.max_job_observations
        )
    finally:
        store.close()
    print(key)
    print(
        f"user {user.name!r}{' (admin)' if user.is_admin else ''}: "
        "keep this key, it is not shown again",
        file=sys.stderr,
    )
    return 0


def cmd_revoke_key(args: argparse.Namespace) -> int:
    """Delete a key by prefix."""
    from service.store import open_store

    store = open_store(_settings(args).resolved_database_url)
    try:
        ok = store.revoke_api_key(args.prefix)
    finally:
        store.close()
    print("revoked" if ok else "no such key", file=sys.stderr)
    return 0 if ok else 1
