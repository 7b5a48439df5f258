"""`bfields-service`: the operator's commands for the service's own state (not the user's CLI).

    bfields-service migrate [--revision REV] [--create-database]   apply the records migrations
    bfields-service db-revision                                    print the database's revision
    bfields-service control                                        run the control process
    bfields-service import-scenes                                  scene records of the bucket -> rows
    bfields-service index-answers                                  answers of earlier succeeded jobs -> rows
    bfields-service callback-secret [--new]                        the callback secret's whsec_ form

Why a separate command from `bfields`: these act on the deployment's database with the
deployment's settings (`BFIELDS_DATABASE_URL`), run from an init container or by hand in an
upgrade; `bfields` is what users run against the API. Every process also migrates at start-up
under the same advisory lock, so running this first is an option, not a step.
"""

from __future__ import annotations

import argparse
import sys

from sqlalchemy.engine import make_url


def _index_answers(url: str) -> int:
    """`index-answers`: the backfill of `jobs.answers.index_existing`, with a progress line per chunk."""
    from bayesian_fields_service.config.settings import get_settings
    from bayesian_fields_service.jobs.answers import index_existing
    from bayesian_fields_service.records.database import open_records
    from bayesian_fields_service.storage.stores import build_store

    settings = get_settings()
    database = open_records(url, migrate_first=True)

    def progress(done: object) -> None:
        print(f"... {done.line()}", flush=True)  # type: ignore[attr-defined]

    done = index_existing(build_store(settings), database, progress=progress)
    print(done.line())
    return 0


def _callback_secret(new: bool) -> int:
    """`callback-secret`: the `whsec_` form of BFIELDS_CALLBACK_SECRET (what a receiver configures
    its Standard Webhooks library with), or with `--new` a fresh secret to set it to."""
    from bayesian_fields_service.config.callback_secret import as_whsec, new_secret
    from bayesian_fields_service.config.settings import get_settings

    if new:
        print(new_secret())
        return 0
    secret = get_settings().callback_secret
    if secret is None:
        print("error: BFIELDS_CALLBACK_SECRET is not set (callbacks are off); "
              "`bfields-service callback-secret --new` makes one", file=sys.stderr)  # fmt: skip
        return 2
    print(as_whsec(secret.get_secret_value()))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bfields-service", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    migrate = sub.add_parser("migrate", help="apply the records migrations (under the migration lock)")
    migrate.add_argument("--revision", default="head", help="target revision (default: head; 'base' empties)")
    migrate.add_argument("--create-database", action="store_true", help="create the database first if absent")
    sub.add_parser("db-revision", help="print the revision the database is at")
    sub.add_parser(
        "control", help="run the control process (dispatch, recovery, sweeps, callbacks; one replica leads)"
    )
    sub.add_parser(
        "import-scenes", help="rows for the scene records an earlier release kept in the bucket (idempotent)"
    )
    sub.add_parser(
        "index-answers",
        help="answer rows for succeeded jobs that have none (after upgrading to revision 0009; resumable, idempotent)",
    )
    secret = sub.add_parser(
        "callback-secret",
        help="print BFIELDS_CALLBACK_SECRET in the Standard Webhooks 'whsec_' form, for callback receivers",
    )
    secret.add_argument("--new", action="store_true", help="print a fresh random 'whsec_' secret instead")
    args = parser.parse_args(argv)
    if args.command == "callback-secret":
        return _callback_secret(args.new)
    if args.command == "control":
        from bayesian_fields_service.control.process import main as run_control

        return run_control()

    from sqlalchemy.exc import OperationalError

    from bayesian_fields_service.config.settings import get_settings
    from bayesian_fields_service.records.database import create_database, current_revision, head_revision
    from bayesian_fields_service.records.database import migrate as run

    url = get_settings().database_url
    shown = make_url(url).render_as_string(hide_password=True)
    try:
        if args.command == "db-revision":
            print(current_revision(url) or "none", "(head:", head_revision() + ")")
            return 0
        if args.command == "import-scenes":
            from bayesian_fields_service.scenes.legacy_import import run_import

            print(run_import(get_settings()).line())
            return 0
        if args.command == "index-answers":
            return _index_answers(url)
        if args.create_database and create_database(url):
            print(f"created database {make_url(url).database}")
        print(f"{shown}: at revision {run(url, args.revision) or 'none'}")
        return 0
    except OperationalError as exc:
        first = str(exc.orig).strip().splitlines()[0] if exc.orig else str(exc)
        print(
            f"error: cannot reach the records database {shown}: {first} (set BFIELDS_DATABASE_URL)",
            file=sys.stderr,
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
