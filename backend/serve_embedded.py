"""The embedded platform on one machine: `python -m backend.serve_embedded` (what `make run` starts).

Migrates the SQLite database, creates a demo organisation, user and site on first start, generates the
simulator's demo survey, uploads it through the same upload service the API uses, starts its
processing, then runs a local Celery worker (with beat; broker = a SQLite file, no server) and the API
(uvicorn) with the browser UI when it is built. Prints the URL and the demo credentials."""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

DEMO_EMAIL = "demo@georef.local"
# the password policy (core/passwords.py) refuses passwords containing the e-mail's name ("demo"):
# the earlier demo password is replaced on start where a data folder still has it
DEMO_PASSWORD = "quarry-flight-2024"
OLD_DEMO_PASSWORDS = ("georef-demo-2024",)


def _zip_survey(folder: Path) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(folder.rglob("*")):
            rel = f.relative_to(folder).as_posix()
            if f.is_file() and not rel.startswith(("truth/", "ppk/")):
                z.write(f, rel)
    return buf.getvalue()


def _renew_demo_password(s, user) -> None:
    """A demo account made by an earlier version keeps working with the password printed now."""
    from .core import security

    for old in OLD_DEMO_PASSWORDS:
        if security.verify_password(user.password_hash, old):
            user.password_hash = security.hash_password(DEMO_PASSWORD)
            return


def bootstrap_demo(settings, full: bool, seed: int) -> str | None:
    """Create the demo account and survey once; returns the id of the run started (None if it existed)."""
    from sqlalchemy import select

    from .db.session import get_database
    from .models import SiteRole, User
    from .services import accounts, runs, sites, stockpiles, surveys, uploads
    from .services.context import Ctx, Principal
    from .storage import storage_for

    db = get_database(settings.resolved_database_url())
    storage = storage_for(settings)
    with db.session() as s:
        uid = s.scalar(select(User.id).where(User.email == DEMO_EMAIL))
        if uid:
            _renew_demo_password(s, s.get(User, uid))
        if uid and s.scalar(select(SiteRole.site_id).where(SiteRole.user_id == uid).limit(1)):
            return None   # already set up
        if uid is None:
            org = accounts.create_organisation(s, "Demo Earthworks Ltd")
            accounts.create_user(s, org.id, DEMO_EMAIL, DEMO_PASSWORD, "Demo surveyor", is_org_admin=True)
    site_dir = settings.data_dir / "demo_site"
    if not (site_dir / "survey.json").exists():
        from georef_core.sim.scenario import SimulationOptions, simulate_site

        print(f"generating the simulated demo survey ({'~100' if full else '12'} images) in {site_dir} ...",
              flush=True)
        simulate_site(site_dir, seed=seed, options=SimulationOptions() if full else SimulationOptions.small())
    meta = json.loads((site_dir / "survey.json").read_text())
    truth = json.loads((site_dir / "truth" / "stockpiles.geojson").read_text())
    data = _zip_survey(site_dir)
    s = db.sessionmaker()
    try:
        user = s.scalar(select(User).where(User.email == DEMO_EMAIL))
        ctx = Ctx(db=s, settings=settings, storage=storage, principal=Principal(user=user, via="session"))
        site = sites.create_site(ctx, "Demo quarry", meta["project_crs"], None, None,
                                 "Simulated earthworks site (georef simulator) with two stockpiles")
        survey = surveys.create_survey(ctx, site.id, "Demo flight", None, "simulated survey", {})
        for f in truth["features"]:
            ring = [[c[0], c[1]] for c in f["geometry"]["coordinates"][0]]
            stockpiles.create_stockpile(ctx, site.id, f["properties"]["name"], {"type": "Polygon",
                                                                               "coordinates": [ring]},
                                        "plane", f["properties"].get("material", ""), None)
        up = uploads.create_upload(ctx, survey.id, "demo_survey.zip", len(data), hashlib.sha256(data).hexdigest(),
                                   "archive", None)
        ctx.commit()
        tmp = settings.resolved_work_dir() / "tmp" / "demo_upload.part"
        tmp.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(data)
        uploads.store_chunk(ctx, up.id, 0, len(data), tmp)
        tmp.unlink()
        ctx.commit()
        uploads.complete_upload(ctx, up.id)
        run = runs.create_run(ctx, survey.id)
        ctx.commit()   # commits and sends the first step to the local broker
        return run.id
    finally:
        s.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.serve_embedded", description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=8000)
    ap.add_argument("--data-dir", help="where the database, files and broker live (default work_out/platform)")
    ap.add_argument("--full", action="store_true", help="a ~100-image demo survey instead of 12 images")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--no-demo", action="store_true", help="do not create the demo account and survey")
    ap.add_argument("--no-worker", action="store_true", help="do not start the local worker")
    args = ap.parse_args(argv)
    if args.data_dir:
        os.environ["GEOREF_DATA_DIR"] = args.data_dir
    os.environ.setdefault("GEOREF_COOKIE_SECURE", "false")          # plain http on the loopback
    os.environ.setdefault("GEOREF_PUBLIC_URL", f"http://{args.host}:{args.port}")
    from .core.settings import get_settings
    from .db.migrate import upgrade

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url())
    run_id = None if args.no_demo else bootstrap_demo(settings, args.full, args.seed)
    worker = None
    if not args.no_worker:
        log = open(settings.data_dir / "worker.log", "ab")
        queues = ",".join(q for q in (settings.default_queue, settings.heavy_queue) if q)
        worker = subprocess.Popen([sys.executable, "-m", "celery", "-A", "worker.celery_app", "worker", "-B",
                                   "-s", str(settings.data_dir / "beat-schedule"), "-Q", queues, "--pool", "solo",
                                   "--loglevel", "INFO", "-n", "embedded@%h"],
                                  stdout=log, stderr=subprocess.STDOUT, cwd=Path(__file__).resolve().parents[1],
                                  start_new_session=True, preexec_fn=_die_with_parent)
    url = f"http://{args.host}:{args.port}"
    print("\nGeoref web platform (embedded: SQLite, local files, local worker)")
    print(f"  open        {url}/   (API: {url}/api/v1, docs: {url}/docs)")
    if not args.no_demo:
        print(f"  log in as   {DEMO_EMAIL} / {DEMO_PASSWORD}")
    if run_id:
        print(f"  the demo survey is processing (run {run_id}): residual tables and volumes appear in a few "
              "minutes")
    print(f"  data in     {settings.data_dir.resolve()} (worker log: worker.log)\n", flush=True)
    import uvicorn

    def stop_worker(*_):
        if worker is not None:
            stop_process_group(worker)

    # uvicorn re-raises SIGINT/SIGTERM after its graceful shutdown (the process then dies without running
    # `finally`): stop the worker from uvicorn's shutdown instead
    server = uvicorn.Server(uvicorn_config(settings, "backend.main:app", args.host, args.port))
    from .core.http_protocol import raise_open_files_limit

    raise_open_files_limit()   # many idle or slow connections: a descriptor each
    try:
        import asyncio

        async def serve():
            try:
                await server.serve()
            finally:
                stop_worker()
        asyncio.run(serve())
    except KeyboardInterrupt:     # Ctrl-C: uvicorn has shut down, the worker is stopped; no traceback
        pass
    finally:
        stop_worker()
    return 0


def uvicorn_config(settings, app: str, host: str, port: int, **kw):
    """uvicorn's configuration for the embedded server: the HTTP protocol with a header deadline and size
    limit (core/http_protocol.py); the body's deadline is the application's (core/limits.py)."""
    import uvicorn

    from .core.http_protocol import guarded_protocol

    return uvicorn.Config(app, host=host, port=port, log_level=kw.pop("log_level", "warning"),
                          http=guarded_protocol(settings), timeout_keep_alive=5, **kw)


def stop_process_group(proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    """SIGTERM to the worker's process group (the worker and its embedded beat), a wait for every member
    to be gone, SIGKILL to what is left after ``timeout_s``."""
    import time

    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + timeout_s
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        pass
    while time.monotonic() < deadline and _group_alive(proc.pid):
        time.sleep(0.1)
    if _group_alive(proc.pid):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.wait(timeout=10)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def _die_with_parent() -> None:
    """Linux: the worker gets SIGTERM when this process dies, however it dies."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


if __name__ == "__main__":
    raise SystemExit(main())
