"""Response shaping shared by the routes: JSON with ETag / 304, pages with Link headers, files with
Range support (COG readers fetch byte ranges), rendered results."""

from __future__ import annotations

import json
import re
from datetime import date, datetime
from typing import Any

from fastapi import Request, Response
from fastapi.responses import FileResponse, StreamingResponse
from pydantic import BaseModel

from ..core.etag import bytes_etag, if_none_match_hits, version_etag
from ..core.problems import RangeNotSatisfiable
from ..services.display import iso_time
from ..services.pagination import Page
from ..storage import Storage, blob_key


def _dump(data: Any) -> Any:
    if isinstance(data, BaseModel):
        return data.model_dump(mode="json")
    if isinstance(data, list):
        return [_dump(x) for x in data]
    return data


def _json_value(value: Any) -> Any:
    """What json cannot write itself: times as ISO 8601 with 'T' and the zone ('Z' for UTC, as the schemas
    write them; a naive time is UTC), anything else as its text."""
    if isinstance(value, datetime):
        return iso_time(value)
    if isinstance(value, date):
        return value.isoformat()
    return str(value)


def json_response(request: Request, data: Any, status_code: int = 200, etag: str | None = None,
                  headers: dict | None = None) -> Response:
    body = json.dumps(_dump(data), separators=(",", ":"), default=_json_value).encode()
    tag = etag or bytes_etag(body)
    h = {"ETag": tag, "Cache-Control": "private, no-cache", **(headers or {})}
    if status_code == 200 and request.method in ("GET", "HEAD") and if_none_match_hits(
            request.headers.get("if-none-match"), tag):
        return Response(status_code=304, headers=h)
    return Response(body, status_code=status_code, media_type="application/json", headers=h)


def model_response(request: Request, schema: type[BaseModel], obj, status_code: int = 200,
                   headers: dict | None = None) -> Response:
    """One row: its ETag comes from its version counter (If-Match on PATCH/DELETE compares it)."""
    data = schema.model_validate(obj)
    tag = version_etag(obj) if hasattr(obj, "version") else None
    return json_response(request, data, status_code, tag, headers)


def page_response(request: Request, page: Page, schema: type[BaseModel]) -> Response:
    items = [schema.model_validate(x).model_dump(mode="json") for x in page.items]
    links = []
    if page.offset + page.limit < page.total:
        nxt = request.url.include_query_params(offset=page.offset + page.limit, limit=page.limit)
        links.append(f'<{nxt}>; rel="next"')
    if page.offset > 0:
        prv = request.url.include_query_params(offset=max(0, page.offset - page.limit), limit=page.limit)
        links.append(f'<{prv}>; rel="prev"')
    headers = {"X-Total-Count": str(page.total)}
    if links:
        headers["Link"] = ", ".join(links)
    return json_response(request, {"items": items, "total": page.total, "limit": page.limit, "offset": page.offset},
                         headers=headers)


_UNSAFE_FILENAME = re.compile(r"[^A-Za-z0-9._ -]")


def attachment(filename: str) -> str:
    """Content-Disposition of a download: an ASCII name without quotes or separators (a name never
    breaks out of the header), the exact name as RFC 5987 filename* when it differs."""
    from urllib.parse import quote

    plain = _UNSAFE_FILENAME.sub("_", filename)[:200].strip() or "download"
    if plain == filename:
        return f'attachment; filename="{plain}"'
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(filename[:200], safe='')}"


def bytes_response(request: Request, body: bytes, media_type: str, etag: str, filename: str | None = None) -> Response:
    h = {"ETag": etag, "Cache-Control": "private, max-age=0, must-revalidate"}
    if filename:
        h["Content-Disposition"] = attachment(filename)
    if if_none_match_hits(request.headers.get("if-none-match"), etag):
        return Response(status_code=304, headers=h)
    return Response(body, media_type=media_type, headers=h)


# at most 18 digits a position (any file is shorter than 10**18 bytes): a longer number is refused as
# unsatisfiable before int() is asked to convert it (Python refuses more than 4300 digits: was a 500)
_RANGE = re.compile(r"^bytes=(\d{0,18})-(\d{0,18})$")


SMALL_FILE_BYTES = 1 << 20


def _byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """(start, end) of a 'bytes=START-END' Range header (end exclusive), None without one."""
    if not header:
        return None
    m = _RANGE.match(header.strip())
    if not m or (not m.group(1) and not m.group(2)):
        raise RangeNotSatisfiable("Range: one 'bytes=START-END' range supported", headers={
            "Content-Range": f"bytes */{size}"})
    if m.group(1):
        start = int(m.group(1))
        end = min(int(m.group(2)) + 1, size) if m.group(2) else size
    else:
        start, end = max(0, size - int(m.group(2))), size
    if start >= size or end <= start:
        raise RangeNotSatisfiable("range outside the file", headers={"Content-Range": f"bytes */{size}"})
    return start, end


def blob_response(request: Request, storage: Storage, sha256: str, size: int, media_type: str,
                  filename: str | None = None) -> Response:
    """A stored file, with ETag / 304 and one byte range. Called from the routes' worker thread: a small
    local file is read here in one go (FileResponse stats, opens, reads in 64 KiB chunks and closes with a
    thread hop each: a 3 KB PDF report cost 9.8 ms a request that way, 3.8 ms read here, in process on
    PostgreSQL); large ones and remote ones stream."""
    etag = f'"{sha256[:32]}"'
    headers = {"ETag": etag, "Accept-Ranges": "bytes", "Cache-Control": "private, max-age=0, must-revalidate"}
    if filename:
        headers["Content-Disposition"] = attachment(filename)
    if if_none_match_hits(request.headers.get("if-none-match"), etag):
        return Response(status_code=304, headers=headers)
    key = blob_key(sha256)
    local = storage.local_path(key)
    span = _byte_range(request.headers.get("range"), size)   # a bad range: problem+json on every branch
    if local is not None and size > SMALL_FILE_BYTES:
        return FileResponse(local, media_type=media_type, headers=headers, filename=None)
    if local is not None:
        with open(local, "rb") as f:
            if span is None:
                return Response(f.read(), media_type=media_type, headers=headers)
            f.seek(span[0])
            body = f.read(span[1] - span[0])
        headers["Content-Range"] = f"bytes {span[0]}-{span[1] - 1}/{size}"
        return Response(body, status_code=206, media_type=media_type, headers=headers)
    if span is not None:
        start, end = span
        headers["Content-Range"] = f"bytes {start}-{end - 1}/{size}"
        headers["Content-Length"] = str(end - start)
        return StreamingResponse(storage.iter_bytes(key, start, end), status_code=206, media_type=media_type,
                                 headers=headers)
    headers["Content-Length"] = str(size)
    return StreamingResponse(storage.iter_bytes(key), media_type=media_type, headers=headers)
