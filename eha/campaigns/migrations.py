"""The result database's schema version: which migrations an open database has, and applying
the ones it lacks (:data:`eha.campaigns.schema.MIGRATIONS`, recorded in ``schema_migrations``).

:func:`eha.campaigns.store.connect` reads the version of every database it opens, refuses one
newer than :data:`eha.campaigns.schema.SCHEMA_VERSION` and, on a writable connection only,
applies the missing migrations (docs/scaling.md, *The database's schema version*).
"""

from __future__ import annotations

from eha.campaigns.schema import MIGRATIONS, MIGRATIONS_TABLE
from eha.campaigns.transactions import transaction


def schema_version(con) -> tuple[int, bool]:
    """``(version, has runs)`` of an open database: its last migration recorded in
    ``schema_migrations`` (0: made before versions, or new) and whether it has ``runs``."""
    names = {n for n, in con.execute("SELECT table_name FROM information_schema.tables "
                                     "WHERE table_schema = 'main'").fetchall()}
    version = 0
    if "schema_migrations" in names:
        version = con.execute("SELECT coalesce(max(version), 0) FROM "
                              "schema_migrations").fetchone()[0]
    return int(version), "runs" in names


def migrate(con, version: int) -> list[str]:
    """Apply :data:`eha.campaigns.schema.MIGRATIONS` above ``version`` in one transaction with
    their rows of ``schema_migrations`` (a crash leaves it at ``version``); ``["N: name"]``."""
    from datetime import datetime, timezone

    todo = [m for m in MIGRATIONS if m[0] > version]
    if not todo:
        return []
    now = datetime.now(timezone.utc).replace(tzinfo=None)
    with transaction(con):
        con.execute(MIGRATIONS_TABLE)
        for number, name, statements in todo:
            for sql in statements:
                con.execute(sql)
            con.execute("INSERT INTO schema_migrations VALUES (?, ?, ?)", [number, name, now])
    return [f"{number}: {name}" for number, name, _ in todo]


__all__ = ["schema_version", "migrate"]
