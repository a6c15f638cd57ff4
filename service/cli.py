"""``pba serve`` and ``pba admin ...``, and the ``pba`` console script itself (:func:`main`).

:func:`main` is the solver's command line (:mod:`solver.cli`) with these commands added: the
service imports the solver, never the other way round.

``pba worker`` runs a distributed (Celery) worker and ``pba db`` migrates the store (issue 8)
and prunes old jobs (issue 13).
"""

from __future__ import annotations

import argparse
import sys

from solver import cli as solver_cli


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

    worker = subparsers.add_parser(
        "worker", help="run a distributed (Celery) worker: PBA_BROKER_URL, PBA_DATABASE_URL"
    )
    worker.add_argument(
        "--concurrency", type=int, default=None, help="solves at once (PBA_WORKER_CONCURRENCY)"
    )
    worker.add_argument("--name", default=None, help="Celery node name (default pba-PID@host)")
    worker.add_argument(
        "--small-lane",
        action="store_true",
        help="serve the small-job lane only (queue PBA_CELERY_SMALL_QUEUE): capacity kept for small jobs",
    )
    worker.add_argument(
        "--ping", action="store_true", help="health check: exit 0 if a worker of this host answers"
    )
    worker.set_defaults(func=cmd_worker)

    db = subparsers.add_parser("db", help="job store schema: migrations (Alembic)")
    db_sub = db.add_subparsers(dest="db_command", metavar="ACTION")
    db_sub.add_parser("upgrade", help="migrate the store to the newest schema").set_defaults(
        func=cmd_db_upgrade
    )
    db_sub.add_parser("current", help="print the store's schema revision").set_defaults(
        func=cmd_db_current
    )
    prune = db_sub.add_parser(
        "prune", help="delete finished jobs older than N days (PBA_JOB_RETENTION_DAYS)"
    )
    prune.add_argument(
        "--older-than-days",
        type=float,
        default=None,
        help="age of the finished jobs to delete (default PBA_JOB_RETENTION_DAYS)",
    )
    prune.add_argument(
        "--dry-run", action="store_true", help="list what would be deleted, delete nothing"
    )
    prune.add_argument(
        "--vacuum",
        action="store_true",
        help="then give the freed space back to the file system (SQLite VACUUM; locks the store)",
    )
    prune.set_defaults(func=cmd_db_prune)
    db.set_defaults(func=lambda args: db.print_help() or 2)

    admin = subparsers.add_parser("admin", help="administration: API keys, users, accounting")
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
    su = admin_sub.add_parser("set-user", help="set a user's fair-share weight and limits")
    su.add_argument("--user", required=True, help="user name (must exist)")
    su.add_argument("--weight", type=float, default=None, help="fair-share weight (default 1)")
    su.add_argument(
        "--max-running-jobs", type=int, default=None, help="running cap while others wait"
    )
    su.add_argument("--max-queued-jobs", type=int, default=None, help="per-user limit")
    su.add_argument("--max-job-observations", type=int, default=None, help="per-user limit")
    su.set_defaults(func=cmd_set_user)
    us = admin_sub.add_parser("usage", help="per-user accounting: jobs, CPU and solve seconds")
    us.add_argument("--json", action="store_true", help="JSON instead of a table")
    us.set_defaults(func=cmd_usage)
    rk = admin_sub.add_parser("revoke-key", help="revoke a key by its prefix (pba_<prefix>_...)")
    rk.add_argument("prefix", help="the key's prefix (the part after pba_ up to the next _)")
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
    from solver.raster_gate import lock_down_process

    settings = _settings(args)
    configure_logging(settings.log_level, settings.log_format)
    if settings.auth_required and not settings.require_api_keys:
        print(
            f"binding to {settings.host}: API keys are required (pba admin create-key)",
            file=sys.stderr,
        )
    lock_down_process()  # the raster gate: GDAL off the network, no raster outside an explicit space
    app = create_app(settings)
    app.state.start_gis_early = True
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
    settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
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


def cmd_set_user(args: argparse.Namespace) -> int:
    """Change a user's weight and limits (the ones given)."""
    from service.schemas import UserSettingsUpdate
    from service.store import open_store

    fields = {
        k: getattr(args, k)
        for k in ("weight", "max_running_jobs", "max_queued_jobs", "max_job_observations")
    }
    try:
        update = UserSettingsUpdate(**fields)
    except ValueError as exc:
        print(f"invalid setting: {exc}", file=sys.stderr)
        return 2
    store = open_store(_settings(args).resolved_database_url)
    try:
        if not any(u.name == args.user for u in store.list_users()):
            print(f"no user {args.user!r}", file=sys.stderr)
            return 1
        store.create_user(args.user, **update.model_dump(exclude_none=True))
    finally:
        store.close()
    return 0


def cmd_usage(args: argparse.Namespace) -> int:
    """Print the accounting table."""
    import json

    from service.accounting import accounting
    from service.store import open_store

    store = open_store(_settings(args).resolved_database_url)
    try:
        rows = accounting(store)
    finally:
        store.close()
    if args.json:
        print(json.dumps([r.model_dump() for r in rows], indent=1))
        return 0
    header = ("user", "weight", "wait", "run", "ok", "failed", "dism.", "cpu_s", "solve_s")
    print("{:<20} {:>6} {:>5} {:>4} {:>6} {:>6} {:>6} {:>10} {:>10}".format(*header))
    for r in rows:
        print(
            f"{r.user[:20]:<20} {r.weight:>6g} {r.waiting:>5} {r.running:>4} "
            f"{r.jobs_successful:>6} {r.jobs_failed:>6} {r.jobs_dismissed:>6} "
            f"{r.cpu_seconds:>10.1f} {r.solve_seconds:>10.1f}"
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


def cmd_worker(args: argparse.Namespace) -> int:
    """Run a Celery worker: solves jobs from PBA_BROKER_URL, store at PBA_DATABASE_URL."""
    from service.queue.celery_app import ping_local_workers, worker_main

    if args.ping:
        nodes = ping_local_workers(_settings(args))
        print(", ".join(nodes) or "no worker of this host answered", file=sys.stderr)
        return 0 if nodes else 1
    return worker_main(_settings(args), args.concurrency, args.name, args.small_lane)


def cmd_db_upgrade(args: argparse.Namespace) -> int:
    """Run the store's migrations up to the newest revision."""
    from service.store.schema import upgrade
    from service.store.sql import make_engine

    settings = _settings(args)
    if settings.resolved_database_url.startswith("sqlite"):
        settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    engine = make_engine(settings.resolved_database_url)
    try:
        revision = upgrade(engine)
    finally:
        engine.dispose()
    print(f"store at revision {revision}", file=sys.stderr)
    return 0


def cmd_db_current(args: argparse.Namespace) -> int:
    """Print the store's revision and the newest one this package ships."""
    from service.store.schema import current_revision, head_revision
    from service.store.sql import make_engine

    engine = make_engine(_settings(args).resolved_database_url)
    try:
        with engine.connect() as conn:
            current = current_revision(conn)
    finally:
        engine.dispose()
    print(f"{current or 'none'} (newest: {head_revision()})")
    return 0


def cmd_db_prune(args: argparse.Namespace) -> int:
    """Delete finished jobs older than --older-than-days (or PBA_JOB_RETENTION_DAYS)."""
    from service.retention import MB, prune
    from service.store import open_store

    settings = _settings(args)
    days = args.older_than_days
    if days is None:
        days = settings.job_retention_days or None
    if days is None or days < 0:
        print(
            "give --older-than-days N (N >= 0) or set PBA_JOB_RETENTION_DAYS", file=sys.stderr
        )
        return 2
    store = open_store(settings.resolved_database_url)
    try:
        pruned = prune(store, days, dry_run=args.dry_run)
        for p in pruned:
            print(f"{p.id}\t{p.status.value}\t{p.finished.isoformat()}\t{p.stored_bytes}")
        if args.vacuum and not args.dry_run:
            store.compact()
    finally:
        store.close()
    verb = "would delete" if args.dry_run else "deleted"
    total = sum(p.stored_bytes for p in pruned) / MB
    print(
        f"{verb} {len(pruned)} finished jobs older than {days:g} days ({total:.1f} MB)",
        file=sys.stderr,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """The ``pba`` console script: the solver's commands and the server's (:func:`register`)."""
    return solver_cli.main(argv, extra=(register,))


if __name__ == "__main__":
    sys.exit(main())
