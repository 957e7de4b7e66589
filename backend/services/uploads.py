"""Resumable chunked uploads with checksums, and the attachment of what they carry to a survey.

create (filename, size, sha256, kind?) -> PUT chunks in order (Content-Range; a chunk must start at
`received_bytes`: resuming after a failure is "GET, then send from received_bytes") -> complete: the
size and SHA-256 are verified, the content recognised (never trusted from the name), archives safely
extracted, and the files attached to the survey in one transaction. A refused upload changes nothing
in the survey.

DJI flight folders (photos + ``*_Timestamp.MRK`` + the raw log ``*_PPKRAW.bin``, as the aircraft writes
them, several per survey after battery swaps) are kept together: their files go to
``flights/<flight folder name>/`` (the pipeline ties photos to their flight's MRK by folder). A zip is
searched for folders holding a Timestamp.MRK; a single file says its folder with ``kind=flight`` and
``folder`` (the relative folder it was dropped in, e.g. ``DCIM/100_0004``)."""

from __future__ import annotations

import hashlib
import posixpath
import re
import secrets
import shutil
import tempfile
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

from sqlalchemy import select, update

from ..core.problems import Conflict, PayloadTooLarge, RangeNotSatisfiable, Unprocessable
from ..models import Survey, SurveyFile, Upload, UploadChunk
from ..models.base import utcnow
from . import file_kinds
from .archives import ArchiveLimits, UnsafeArchive, extract_zip
from .context import Ctx
from .new_data import note_new_data
from .permissions import require_survey, require_upload

_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_SAFE_NAME = re.compile(r"[^A-Za-z0-9._+\-() ]")
LAYOUT_FOLDERS = ("rover", "base", "nav", "images", "gcp", "flights", "calibration")
FLIGHTS_FOLDER = "flights"
# DJI names the files of a flight folder <folder>_Timestamp.MRK, <folder>_PPKRAW.bin, <folder>_Rinex.obs ...
_DJI_FLIGHT_FILE = re.compile(r"^(.+?)_(Timestamp\.MRK|PPKRAW\.bin|PPKNAV\.nav|Rinex\.obs|EVENTLOG\.bin)$",
                              re.IGNORECASE)


def sanitise_filename(name: str) -> str:
    base = name.replace("\\", "/").rsplit("/", 1)[-1].strip()
    base = _SAFE_NAME.sub("_", base)[:200].lstrip(".")
    if not base:
        raise Unprocessable(f"filename {name!r} is not usable (empty once path separators and dots are removed)")
    return base


def sanitise_folder(folder: str | None) -> str | None:
    """A relative folder as dropped ('DCIM/100_0004'): each name made safe, '.', '..' and empty names
    dropped; None when nothing is left."""
    if folder is None:
        return None
    parts = []
    for part in folder.replace("\\", "/").split("/"):
        part = _SAFE_NAME.sub("_", part.strip())[:200].lstrip(".")
        if part:
            parts.append(part)
    return "/".join(parts)[:500] or None


def flight_name(folder: str | None, filename: str = "") -> str | None:
    """The name of a DJI flight's folder under flights/: the last name of the folder the file was in,
    else the prefix of a DJI flight file name ('100_0004' of '100_0004_Timestamp.MRK'), else None."""
    folder = sanitise_folder(folder)
    if folder:
        return folder.rsplit("/", 1)[-1]
    m = _DJI_FLIGHT_FILE.match(posixpath.basename(filename))
    if m:
        return sanitise_folder(m.group(1))
    return None


# ----------------------------------------------------------------------------------------- create / status


def create_upload(ctx: Ctx, survey_id: str, filename: str, size: int, sha256: str, kind: str | None,
                  role: str | None, folder: str | None = None) -> Upload:
    require_survey(ctx, survey_id, "editor")
    if size <= 0:
        raise Unprocessable("size: the file is empty")
    if size > ctx.settings.max_upload_bytes:
        raise PayloadTooLarge(f"size: {size} bytes is more than the limit of {ctx.settings.max_upload_bytes} bytes "
                              "per file; split the image set into several archives")
    sha256 = sha256.lower()
    if not _SHA256.match(sha256):
        raise Unprocessable("sha256: 64 hexadecimal characters expected")
    kind = file_kinds.HINT_ALIASES.get(kind, kind)
    if kind is not None and kind not in file_kinds.HINTS:
        raise Unprocessable(f"kind: one of {', '.join(file_kinds.HINTS)}")
    if role is not None and role not in ("rover", "base"):
        raise Unprocessable("role: rover or base")
    if kind in ("rover", "base"):
        role = kind
    folder = sanitise_folder(folder)
    if kind == "flight" and not folder and flight_name(None, filename) is None:
        raise Unprocessable("folder: kind=flight needs the flight folder the file was in (e.g. DCIM/100_0004), "
                            "so that its photos, Timestamp.MRK and raw log stay together")
    up = Upload(survey_id=survey_id, filename=sanitise_filename(filename), size=size, sha256=sha256, kind=kind,
                role=role, folder=folder, created_by=ctx.user.id,
                expires_at=utcnow() + timedelta(hours=ctx.settings.upload_expiry_hours))
    ctx.db.add(up)
    ctx.db.flush()
    return up


def get_upload(ctx: Ctx, upload_id: str) -> Upload:
    return require_upload(ctx, upload_id, "viewer")


def list_uploads(ctx: Ctx, survey_id: str) -> list[Upload]:
    require_survey(ctx, survey_id, "viewer")
    return list(ctx.db.scalars(select(Upload).where(Upload.survey_id == survey_id).order_by(Upload.created_at.desc())))


def parse_content_range(header: str | None, content_length: int | None) -> tuple[int, int, int | None]:
    """(start, end exclusive, total) from 'bytes START-END/TOTAL' (END inclusive, TOTAL may be '*')."""
    if not header:
        raise Unprocessable("Content-Range header required: bytes START-END/SIZE")
    m = re.fullmatch(r"\s*bytes\s+(\d{1,18})-(\d{1,18})/(\d{1,18}|\*)\s*", header)
    if not m:
        raise Unprocessable(f"Content-Range {header[:80]!r} malformed; expected 'bytes START-END/SIZE' "
                            "(positions of at most 18 digits)")
    start, end = int(m.group(1)), int(m.group(2)) + 1
    total = None if m.group(3) == "*" else int(m.group(3))
    if end <= start:
        raise Unprocessable("Content-Range: END before START")
    if content_length is not None and content_length != end - start:
        raise Unprocessable(f"Content-Range covers {end - start} bytes but Content-Length is {content_length}")
    return start, end, total


def check_chunk(ctx: Ctx, upload_id: str, start: int, end: int, total: int | None) -> Upload | None:
    """Before the body is read: refuse what cannot be accepted. Returns the upload when the chunk was
    already received (an idempotent retry), else None."""
    up = require_upload(ctx, upload_id, "editor")
    if up.state != "open":
        raise Conflict(f"upload is {up.state}; chunks are accepted only while it is open",
                       received_bytes=up.received_bytes)
    if total is not None and total != up.size:
        raise RangeNotSatisfiable(f"Content-Range total {total} differs from the declared size {up.size}")
    if end > up.size:
        raise RangeNotSatisfiable(f"chunk ends at byte {end}, beyond the declared size {up.size}",
                                  received_bytes=up.received_bytes)
    if end - start > ctx.settings.max_chunk_bytes:
        raise PayloadTooLarge(f"chunk of {end - start} bytes; at most {ctx.settings.max_chunk_bytes} per request")
    if end <= up.received_bytes:
        return up
    if start != up.received_bytes:
        raise Conflict(f"chunk starts at byte {start} but the upload has {up.received_bytes} bytes; send from there",
                       received_bytes=up.received_bytes)
    return None


def store_chunk(ctx: Ctx, upload_id: str, start: int, end: int, data_path: Path, move: bool = False) -> Upload:
    """Store a received chunk (already written to data_path) and advance received_bytes atomically.
    ``move``: data_path is handed to the store (renamed into place on a local store: the chunk's bytes
    are written once, where they were received)."""
    length = data_path.stat().st_size
    if length != end - start:
        raise Unprocessable(f"received {length} bytes but Content-Range announced {end - start} (interrupted?); "
                            "resend the chunk")
    key = f"uploads/{upload_id}/{start:016d}-{secrets.token_hex(4)}"
    ctx.storage.put_file(key, data_path, move=move)
    n = ctx.db.execute(update(Upload).where(Upload.id == upload_id, Upload.state == "open",
                                            Upload.received_bytes == start)
                       .values(received_bytes=end, updated_at=utcnow())).rowcount
    if n != 1:
        ctx.storage.delete(key)
        up = ctx.db.get(Upload, upload_id)
        ctx.db.refresh(up)
        raise Conflict("another request stored this part first", received_bytes=up.received_bytes)
    ctx.db.add(UploadChunk(upload_id=upload_id, offset=start, length=length, key=key))
    ctx.db.flush()
    up = ctx.db.get(Upload, upload_id)
    ctx.db.refresh(up)
    return up


def abort_upload(ctx: Ctx, upload_id: str) -> None:
    up = require_upload(ctx, upload_id, "editor")
    if up.state == "complete":
        raise Conflict("upload is complete; delete the survey's files instead")
    up.state = "aborted"
    _drop_chunks(ctx, up.id)


def _drop_chunks(ctx: Ctx, upload_id: str) -> None:
    ctx.db.execute(UploadChunk.__table__.delete().where(UploadChunk.upload_id == upload_id))
    ctx.storage.delete_prefix(f"uploads/{upload_id}/")


def expire_uploads(db, storage) -> int:
    """Abort open uploads past their expiry (periodic task)."""
    rows = list(db.scalars(select(Upload).where(Upload.state == "open", Upload.expires_at < utcnow())))
    for up in rows:
        up.state = "aborted"
        up.error = "expired before completion"
        db.execute(UploadChunk.__table__.delete().where(UploadChunk.upload_id == up.id))
        storage.delete_prefix(f"uploads/{up.id}/")
    return len(rows)


# ----------------------------------------------------------------------------------------- complete


@dataclass
class Placed:
    path: str
    kind: str
    role: str | None
    meta: dict
    local: Path


class Refused(Exception):
    pass


def _guess_role(name: str) -> str | None:
    low = name.lower()
    if "base" in low or "ref" in low:
        return "base"
    if any(w in low for w in ("rover", "drone", "uav", "uas")):
        return "rover"
    return None


def _place(kind: str, name: str, role: str | None, hint: str | None,
           flight: str | None = None) -> tuple[str, str | None]:
    """(path in the survey folder, role) of a recognised file; ``flight``: the DJI flight folder it
    belongs to (its files go to flights/<flight>/, the raw log being the rover's)."""
    base = posixpath.basename(name)
    if flight is not None:
        return f"{FLIGHTS_FOLDER}/{flight}/{base}", ("rover" if kind in file_kinds.OBSERVATION_KINDS else None)
    if kind == "site-calibration":   # one calibration per survey (the datum step refuses two): fixed names
        return ("calibration/pairs.csv" if base.lower().endswith(".csv") else "calibration/site_calibration.json"), None
    if kind == "dji-mrk":
        raise Refused("a DJI Timestamp.MRK belongs with its flight's photos: upload it with kind=flight and "
                      "folder=<the flight folder>, or zip the flight folder")
    if kind in file_kinds.OBSERVATION_KINDS:
        if kind in ("ubx", "rtcm3") and hint == "nav":
            return f"nav/{base}", None
        role = role or _guess_role(base)
        return (f"{role}/{base}" if role else f"unassigned/{base}"), role
    return {"rinex-nav": f"nav/{base}", "image": f"images/{base}", "events": "events.csv",
            "points": "gcp/points.csv", "gcp-list": "gcp/gcp_list.txt",
            "survey-metadata": "survey.json"}[kind], None


def _strip_common_folder(names: list[str]) -> str:
    firsts = {n.split("/", 1)[0] for n in names}
    if len(firsts) == 1 and all("/" in n for n in names):
        top = firsts.pop()
        if top not in LAYOUT_FOLDERS:
            return top + "/"
    return ""


def _flight_folders(recognised: list[tuple], archive_name: str, hint: str | None,
                    folder: str | None) -> dict[str, str]:
    """Folders of an archive that are DJI flights -> their name under flights/. A flight folder is one
    holding a Timestamp.MRK, or one already under flights/ (a survey folder zipped back); with
    kind=flight, the archive's top folder too. Names are the folders' own names (the whole relative path
    when two flights share a name)."""
    mrks: dict[str, list[str]] = {}
    dirs = set()
    for name, rec, _exc in recognised:
        d = posixpath.dirname(name)
        dirs.add(d)
        if rec is not None and rec.kind == "dji-mrk":
            mrks.setdefault(d, []).append(posixpath.basename(name))
    for d, names in mrks.items():
        if len(names) > 1:
            raise Refused(f"{d or 'the archive'} holds {len(names)} Timestamp.MRK files ({', '.join(sorted(names))}): "
                          "keep each flight in its own folder")
    flight_dirs = set(mrks)
    prefix = _strip_common_folder([n for n, _r, _e in recognised])
    for d in dirs:
        rel = d[len(prefix):] if prefix and d.startswith(prefix) else d
        if rel.startswith(f"{FLIGHTS_FOLDER}/") and rel.count("/") == 1:
            flight_dirs.add(d)
    if hint == "flight":
        flight_dirs.add(prefix.rstrip("/"))
    out: dict[str, str] = {}
    for d in sorted(flight_dirs):
        if d:
            out[d] = sanitise_folder(posixpath.basename(d)) or "flight"
        else:   # files at the top of the archive: the MRK's name, the folder given, or the archive's name
            mrk = (mrks.get("") or [""])[0]
            out[d] = flight_name(folder, mrk) or sanitise_folder(posixpath.splitext(archive_name)[0]) or "flight"
    names = list(out.values())
    for d, n in list(out.items()):
        if names.count(n) > 1:
            out[d] = sanitise_folder(d.replace("/", "_")) or n
    return out


def _place_archive_members(members, hint: str | None, role: str | None, archive_name: str = "",
                           folder: str | None = None) -> tuple[list[Placed], list[dict]]:
    placed: list[Placed] = []
    ignored: list[dict] = []
    recognised: list[tuple] = []
    for m in members:
        try:
            recognised.append((m.name, file_kinds.recognise(m.path, m.name), None))
        except file_kinds.UnrecognisedFile as exc:
            if exc.kind == "dji-mrk":     # a damaged MRK would leave its flight's photos without exposures
                raise Refused(f"{m.name}: {exc}") from None
            recognised.append((m.name, None, exc))
    flights = _flight_folders(recognised, archive_name, hint, folder)
    prefix = _strip_common_folder([m.name for m in members])
    for m, (_n, rec, exc) in zip(members, recognised):
        name = m.name[len(prefix):] if prefix else m.name
        top = name.split("/", 1)[0] if "/" in name else ""
        if rec is None:
            ignored.append({"name": m.name, "reason": str(exc)})
            continue
        if rec.kind == "archive":
            ignored.append({"name": m.name, "reason": "archive inside the archive (not extracted)"})
            continue
        flight = flights.get(posixpath.dirname(m.name))
        if flight is not None:
            if rec.kind not in file_kinds.FLIGHT_KINDS:
                ignored.append({"name": m.name, "reason": f"{file_kinds.KIND_WORDS[rec.kind]} in the DJI flight "
                                                          f"folder {flight} (not a flight file)"})
                continue
            path, r = _place(rec.kind, name, None, None, flight)
            placed.append(Placed(path, rec.kind, r, rec.meta, m.path))
            continue
        if top and top not in LAYOUT_FOLDERS:
            ignored.append({"name": m.name, "reason": f"outside the survey folder layout ({top}/)"})
            continue
        expected = {"rover": file_kinds.HINTS["rover"], "base": file_kinds.HINTS["base"], "nav": file_kinds.HINTS["nav"],
                    "images": ("image",), "gcp": ("points", "gcp-list"), "calibration": ("site-calibration",),
                    FLIGHTS_FOLDER: ()}.get(top)
        if expected is not None and rec.kind not in expected:
            where = f"{top}/" if top != FLIGHTS_FOLDER else f"{posixpath.dirname(name)}/ (not a flight folder)"
            ignored.append({"name": m.name, "reason": f"{file_kinds.KIND_WORDS[rec.kind]} in {where}"})
            continue
        if not top and hint in file_kinds.HINTS and hint not in ("archive", "flight") \
                and rec.kind not in file_kinds.HINTS[hint]:
            ignored.append({"name": m.name, "reason": f"{file_kinds.KIND_WORDS[rec.kind]}, not what kind={hint} expects"})
            continue
        r = top if top in ("rover", "base") else role
        h = "nav" if top == "nav" else hint
        path, r = _place(rec.kind, name, r, h)
        placed.append(Placed(path, rec.kind, r, rec.meta, m.path))
    seen: dict[str, str] = {}
    for p in placed:
        if p.path in seen:
            raise Refused(f"two archive members would both become {p.path}; keep one")
        seen[p.path] = p.path
    return placed, ignored


def complete_upload(ctx: Ctx, upload_id: str) -> Upload:
    up = require_upload(ctx, upload_id, "editor")
    if up.state == "complete":
        return up
    if up.state != "open":
        raise Conflict(f"upload is {up.state}" + (f": {up.error}" if up.error else ""))
    if up.received_bytes != up.size:
        raise Conflict(f"upload incomplete: {up.received_bytes} of {up.size} bytes received; send the rest first",
                       received_bytes=up.received_bytes)
    claimed = ctx.db.execute(update(Upload).where(Upload.id == up.id, Upload.state == "open")
                             .values(state="verifying", updated_at=utcnow())).rowcount
    ctx.db.commit()
    if claimed != 1:
        raise Conflict("the upload is being completed by another request")
    tmp_root = Path(tempfile.mkdtemp(prefix="georef-upload-", dir=_tmp_dir(ctx)))
    try:
        try:
            result = _verify_and_attach(ctx, up, tmp_root)
        except Refused as exc:
            ctx.db.rollback()
            _fail(ctx, up.id, str(exc))
            raise Unprocessable(f"{up.filename}: {exc}", upload_id=up.id) from None
        except BaseException:
            ctx.db.rollback()
            ctx.db.execute(update(Upload).where(Upload.id == up.id).values(state="open"))
            ctx.db.commit()
            raise
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    ctx.db.refresh(up)
    return up if result else up


def _tmp_dir(ctx: Ctx) -> str:
    d = ctx.settings.resolved_work_dir() / "tmp"
    d.mkdir(parents=True, exist_ok=True)
    return str(d)


def _fail(ctx: Ctx, upload_id: str, reason: str) -> None:
    ctx.db.execute(update(Upload).where(Upload.id == upload_id).values(state="failed", error=reason, updated_at=utcnow()))
    _drop_chunks(ctx, upload_id)
    ctx.db.commit()


def _assemble(ctx: Ctx, up: Upload, chunks: list[tuple[int, int, str]], dest: Path) -> str:
    h = hashlib.sha256()
    pos = 0
    with open(dest, "wb") as out:
        for offset, length, key in chunks:
            if offset != pos:
                raise Refused(f"stored parts do not join at byte {pos}; upload the file again")
            for block in ctx.storage.iter_bytes(key):
                h.update(block)
                out.write(block)
            pos += length
    if pos != up.size:
        raise Refused(f"stored parts hold {pos} bytes, not the declared {up.size}; upload the file again")
    return h.hexdigest()


def _verify_and_attach(ctx: Ctx, up: Upload, tmp: Path) -> bool:
    """Read what is needed, end the transaction, do the slow part (join the parts, hash, recognise,
    extract, store the blobs) holding no database lock, then write the rows in one short transaction:
    on SQLite a write transaction blocks every other writer for as long as it is open."""
    chunks = [(c.offset, c.length, c.key) for c in ctx.db.scalars(
        select(UploadChunk).where(UploadChunk.upload_id == up.id).order_by(UploadChunk.offset))]
    ctx.db.commit()      # nothing written since the claim: this only ends the transaction
    whole = tmp / up.filename
    got = _assemble(ctx, up, chunks, whole)
    if got != up.sha256:
        raise Refused(f"SHA-256 mismatch: declared {up.sha256}, received data has {got} (corrupted in transit or "
                      "wrong checksum); upload the file again")
    try:
        rec = file_kinds.recognise(whole, up.filename)
    except file_kinds.UnrecognisedFile as exc:
        if exc.kind is not None:
            raise Refused(str(exc)) from None
        raise Refused(f"not a survey file: {exc}. Expected RINEX observation/navigation, u-blox UBX, RTCM 3 logs, "
                      "DJI Timestamp.MRK, JPEG/TIFF images, events.csv, points.csv, gcp_list.txt or a zip archive "
                      "of these") from None
    ignored: list[dict] = []
    if rec.kind == "archive":
        s = ctx.settings
        limits = ArchiveLimits(max_members=s.max_archive_members, max_total_bytes=s.max_archive_total_bytes,
                               max_member_bytes=s.max_upload_bytes, max_ratio=s.max_archive_ratio)
        try:
            members = extract_zip(whole, tmp / "x", limits)
        except UnsafeArchive as exc:
            raise Refused(f"archive refused: {exc}") from None
        placed, ignored = _place_archive_members(members, up.kind, up.role, up.filename, up.folder)
        if not placed:
            raise Refused("the archive holds no survey file" + (
                f" ({len(ignored)} ignored: " + "; ".join(f"{i['name']}: {i['reason']}" for i in ignored[:5]) + ")"
                if ignored else ""))
    else:
        if up.kind and up.kind != "archive" and rec.kind not in file_kinds.HINTS[up.kind]:
            raise Refused(f"this is {file_kinds.KIND_WORDS[rec.kind]}, but the upload was declared kind={up.kind} "
                          f"({' or '.join(file_kinds.KIND_WORDS[k] for k in file_kinds.HINTS[up.kind])} expected)")
        if up.kind == "archive":
            raise Refused(f"this is {file_kinds.KIND_WORDS[rec.kind]}, not a zip archive")
        flight = None
        if up.kind == "flight" or rec.kind == "dji-mrk":
            flight = flight_name(up.folder, up.filename)
        path, role = _place(rec.kind, up.filename, up.role, up.kind, flight)
        placed = [Placed(path, rec.kind, role, rec.meta, whole)]
    # content-addressed blobs first, outside any transaction (harmless if the transaction below fails),
    # then the rows at once
    stored = [ctx.storage.put_blob(p.local) for p in placed]
    survey = ctx.db.get(Survey, up.survey_id)
    attached = []
    kinds = set()
    for p, (sha, size) in zip(placed, stored):
        row = ctx.db.scalar(select(SurveyFile).where(SurveyFile.survey_id == up.survey_id, SurveyFile.path == p.path))
        replaced = row is not None and row.sha256 != sha
        if row is None:
            row = SurveyFile(survey_id=up.survey_id, path=p.path)
            ctx.db.add(row)
        if row.sha256 != sha or row.kind != p.kind:
            kinds.add(p.kind if p.role is None else f"{p.kind}:{p.role}")
        row.kind, row.role, row.sha256, row.size, row.meta, row.upload_id = p.kind, p.role, sha, size, p.meta, up.id
        attached.append({"path": p.path, "kind": p.kind, "role": p.role, "size": size, "sha256": sha,
                         "replaced": replaced})
    survey.version += 1
    ctx.db.execute(update(Upload).where(Upload.id == up.id).values(
        state="complete", error=None, updated_at=utcnow(),
        result={"files": attached, "ignored": ignored}))
    ctx.db.execute(UploadChunk.__table__.delete().where(UploadChunk.upload_id == up.id))
    ctx.db.flush()

    if any(k.endswith(":base") or k == "rinex-nav" for k in kinds):
        note_new_data(ctx, survey, "base")
    if "points" in kinds:
        note_new_data(ctx, survey, "points")
    ctx.db.commit()
    ctx.storage.delete_prefix(f"uploads/{up.id}/")
    return True
