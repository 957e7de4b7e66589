"""Resumable chunked uploads with checksums, and the attachment of what they carry to a survey.

create (filename, size, sha256, kind?) -> PUT chunks in order (Content-Range; a chunk must start at
`received_bytes`: resuming after a failure is "GET, then send from received_bytes") -> complete: the
size and SHA-256 are verified, the content recognised (never trusted from the name), archives safely
extracted, and the files attached to the survey in one transaction. A refused upload changes nothing
in the survey."""

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
from .permissions import require_survey, require_upload

_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_SAFE_NAME = re.compile(r"[^A-Za-z0-9._+\-() ]")
LAYOUT_FOLDERS = ("rover", "base", "nav", "images", "gcp")


def sanitise_filename(name: str) -> str:
    base = name.replace("\\", "/").rsplit("/", 1)[-1].strip()
    base = _SAFE_NAME.sub("_", base)[:200].lstrip(".")
    if not base:
        raise Unprocessable(f"filename {name!r} is not usable (empty once path separators and dots are removed)")
    return base


# ----------------------------------------------------------------------------------------- create / status


def create_upload(ctx: Ctx, survey_id: str, filename: str, size: int, sha256: str, kind: str | None,
                  role: str | None) -> Upload:
    require_survey(ctx, survey_id, "editor")
    if size <= 0:
        raise Unprocessable("size: the file is empty")
    if size > ctx.settings.max_upload_bytes:
        raise PayloadTooLarge(f"size: {size} bytes is more than the limit of {ctx.settings.max_upload_bytes} bytes "
                              "per file; split the image set into several archives")
    sha256 = sha256.lower()
    if not _SHA256.match(sha256):
        raise Unprocessable("sha256: 64 hexadecimal characters expected")
    if kind is not None and kind not in file_kinds.HINTS:
        raise Unprocessable(f"kind: one of {', '.join(file_kinds.HINTS)}")
    if role is not None and role not in ("rover", "base"):
        raise Unprocessable("role: rover or base")
    if kind in ("rover", "base"):
        role = kind
    up = Upload(survey_id=survey_id, filename=sanitise_filename(filename), size=size, sha256=sha256, kind=kind,
                role=role, created_by=ctx.user.id,
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
    m = re.fullmatch(r"\s*bytes\s+(\d+)-(\d+)/(\d+|\*)\s*", header)
    if not m:
        raise Unprocessable(f"Content-Range {header!r} malformed; expected 'bytes START-END/SIZE'")
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


def store_chunk(ctx: Ctx, upload_id: str, start: int, end: int, data_path: Path) -> Upload:
    """Store a received chunk (already written to data_path) and advance received_bytes atomically."""
    length = data_path.stat().st_size
    if length != end - start:
        raise Unprocessable(f"received {length} bytes but Content-Range announced {end - start} (interrupted?); "
                            "resend the chunk")
    key = f"uploads/{upload_id}/{start:016d}-{secrets.token_hex(4)}"
    ctx.storage.put_file(key, data_path)
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


def _place(kind: str, name: str, role: str | None, hint: str | None) -> tuple[str, str | None]:
    base = posixpath.basename(name)
    if kind in ("rinex-obs", "ubx"):
        if kind == "ubx" and hint == "nav":
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


def _place_archive_members(members, hint: str | None, role: str | None) -> tuple[list[Placed], list[dict]]:
    placed: list[Placed] = []
    ignored: list[dict] = []
    prefix = _strip_common_folder([m.name for m in members])
    for m in members:
        name = m.name[len(prefix):] if prefix else m.name
        folder = name.split("/", 1)[0] if "/" in name else ""
        try:
            rec = file_kinds.recognise(m.path, name)
        except file_kinds.UnrecognisedFile as exc:
            ignored.append({"name": m.name, "reason": str(exc)})
            continue
        if rec.kind == "archive":
            ignored.append({"name": m.name, "reason": "archive inside the archive (not extracted)"})
            continue
        if folder and folder not in LAYOUT_FOLDERS:
            ignored.append({"name": m.name, "reason": f"outside the survey folder layout ({folder}/)"})
            continue
        expected = {"rover": ("rinex-obs", "ubx"), "base": ("rinex-obs", "ubx"), "nav": ("rinex-nav", "ubx"),
                    "images": ("image",), "gcp": ("points", "gcp-list")}.get(folder)
        if expected and rec.kind not in expected:
            ignored.append({"name": m.name, "reason": f"{file_kinds.KIND_WORDS[rec.kind]} in {folder}/"})
            continue
        if not folder and hint in file_kinds.HINTS and hint != "archive" and rec.kind not in file_kinds.HINTS[hint]:
            ignored.append({"name": m.name, "reason": f"{file_kinds.KIND_WORDS[rec.kind]}, not what kind={hint} expects"})
            continue
        r = folder if folder in ("rover", "base") else role
        h = "nav" if folder == "nav" else hint
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


def _assemble(ctx: Ctx, up: Upload, dest: Path) -> str:
    chunks = list(ctx.db.scalars(select(UploadChunk).where(UploadChunk.upload_id == up.id)
                                 .order_by(UploadChunk.offset)))
    h = hashlib.sha256()
    pos = 0
    with open(dest, "wb") as out:
        for c in chunks:
            if c.offset != pos:
                raise Refused(f"stored parts do not join at byte {pos}; upload the file again")
            for block in ctx.storage.iter_bytes(c.key):
                h.update(block)
                out.write(block)
            pos += c.length
    if pos != up.size:
        raise Refused(f"stored parts hold {pos} bytes, not the declared {up.size}; upload the file again")
    return h.hexdigest()


def _verify_and_attach(ctx: Ctx, up: Upload, tmp: Path) -> bool:
    whole = tmp / up.filename
    got = _assemble(ctx, up, whole)
    if got != up.sha256:
        raise Refused(f"SHA-256 mismatch: declared {up.sha256}, received data has {got} (corrupted in transit or "
                      "wrong checksum); upload the file again")
    try:
        rec = file_kinds.recognise(whole, up.filename)
    except file_kinds.UnrecognisedFile as exc:
        raise Refused(f"not a survey file: {exc}. Expected RINEX observation/navigation, u-blox UBX, JPEG/TIFF "
                      "images, events.csv, points.csv, gcp_list.txt or a zip archive of these") from None
    ignored: list[dict] = []
    if rec.kind == "archive":
        s = ctx.settings
        limits = ArchiveLimits(max_members=s.max_archive_members, max_total_bytes=s.max_archive_total_bytes,
                               max_member_bytes=s.max_upload_bytes, max_ratio=s.max_archive_ratio)
        try:
            members = extract_zip(whole, tmp / "x", limits)
        except UnsafeArchive as exc:
            raise Refused(f"archive refused: {exc}") from None
        placed, ignored = _place_archive_members(members, up.kind, up.role)
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
        path, role = _place(rec.kind, up.filename, up.role, up.kind)
        placed = [Placed(path, rec.kind, role, rec.meta, whole)]
    # content-addressed blobs first (harmless if the transaction below fails), then the rows at once
    survey = ctx.db.get(Survey, up.survey_id)
    attached = []
    kinds = set()
    for p in placed:
        sha, size = ctx.storage.put_blob(p.local)
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
    from .schedules import note_new_data

    if any(k.endswith(":base") or k == "rinex-nav" for k in kinds):
        note_new_data(ctx, survey, "base")
    if "points" in kinds:
        note_new_data(ctx, survey, "points")
    ctx.db.commit()
    ctx.storage.delete_prefix(f"uploads/{up.id}/")
    return True
