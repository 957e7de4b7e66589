"""Create a user (and its organisation): `python -m backend.create_user EMAIL [--org NAME] [--org-admin]`.

The password is read from GEOREF_NEW_PASSWORD or asked for. The first user of a fresh deployment is
created this way; organisation admins add the others (POST /api/v1/users)."""

from __future__ import annotations

import argparse
import getpass
import os
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.create_user")
    ap.add_argument("email")
    ap.add_argument("--name", default="")
    ap.add_argument("--org", default="", help="organisation name (created); default: the user's e-mail domain")
    ap.add_argument("--org-id", help="add to this existing organisation instead")
    ap.add_argument("--org-admin", action="store_true", help="may add users to the organisation")
    args = ap.parse_args(argv)
    password = os.environ.get("GEOREF_NEW_PASSWORD") or getpass.getpass("password: ")
    from .core.problems import Problem
    from .core.settings import get_settings
    from .db.migrate import upgrade
    from .db.session import get_database
    from .services import accounts

    settings = get_settings()
    upgrade(settings.resolved_database_url())
    try:
        with get_database(settings.resolved_database_url()).session() as s:
            org_id = args.org_id or accounts.create_organisation(s, args.org or args.email.split("@")[-1]).id
            user = accounts.create_user(s, org_id, args.email, password, args.name, args.org_admin)
            print(f"user {user.email} ({user.id}) in organisation {org_id}")
    except Problem as exc:
        print(f"create_user: error: {exc.detail}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
