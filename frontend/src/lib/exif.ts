/**
 * The capture time of a JPEG/TIFF photo from its EXIF block: DateTimeOriginal (+ SubSecTimeOriginal and
 * OffsetTimeOriginal when present). Only the first kilobytes of the file are needed.
 */

export interface ExifTime {
  /** Milliseconds since 1970 in UTC when the offset is known, else the camera's local clock read as UTC. */
  ms: number;
  hasOffset: boolean;
}

const TAG_EXIF_IFD = 0x8769;
const TAG_DATETIME_ORIGINAL = 0x9003;
const TAG_OFFSET_TIME_ORIGINAL = 0x9011;
const TAG_SUBSEC_TIME_ORIGINAL = 0x9291;

function tiffTags(dv: DataView, base: number, ifdOff: number, little: boolean): Map<number, { type: number; count: number; valueOff: number }> {
  const tags = new Map<number, { type: number; count: number; valueOff: number }>();
  const at = base + ifdOff;
  if (at + 2 > dv.byteLength) return tags;
  const n = dv.getUint16(at, little);
  for (let k = 0; k < n; k++) {
    const e = at + 2 + k * 12;
    if (e + 12 > dv.byteLength) break;
    const tag = dv.getUint16(e, little);
    const type = dv.getUint16(e + 2, little);
    const count = dv.getUint32(e + 4, little);
    const size = count * ([0, 1, 1, 2, 4, 8, 1, 1, 2, 4, 8, 4, 8][type] ?? 1);
    const valueOff = size <= 4 ? e + 8 : base + dv.getUint32(e + 8, little);
    tags.set(tag, { type, count, valueOff });
  }
  return tags;
}

function ascii(dv: DataView, off: number, count: number): string {
  let s = "";
  for (let i = 0; i < count && off + i < dv.byteLength; i++) {
    const c = dv.getUint8(off + i);
    if (c === 0) break;
    s += String.fromCharCode(c);
  }
  return s.trim();
}

/** EXIF capture time from a TIFF structure starting at `base` in the view. */
function timeFromTiff(dv: DataView, base: number): ExifTime | null {
  if (base + 8 > dv.byteLength) return null;
  const bo = dv.getUint16(base);
  const little = bo === 0x4949;
  if (!little && bo !== 0x4d4d) return null;
  const ifd0 = dv.getUint32(base + 4, little);
  const t0 = tiffTags(dv, base, ifd0, little);
  const exifPtr = t0.get(TAG_EXIF_IFD);
  if (!exifPtr) return null;
  const exifOff = dv.getUint32(exifPtr.valueOff, little);
  const t = tiffTags(dv, base, exifOff, little);
  const dto = t.get(TAG_DATETIME_ORIGINAL);
  if (!dto) return null;
  const s = ascii(dv, dto.valueOff, dto.count);
  const m = /^(\d{4}):(\d{2}):(\d{2}) (\d{2}):(\d{2}):(\d{2})/.exec(s);
  if (!m) return null;
  let ms = Date.UTC(+m[1], +m[2] - 1, +m[3], +m[4], +m[5], +m[6]);
  const sub = t.get(TAG_SUBSEC_TIME_ORIGINAL);
  if (sub) {
    const digits = ascii(dv, sub.valueOff, sub.count).replace(/\D/g, "");
    if (digits) ms += Math.round(parseFloat(`0.${digits}`) * 1000);
  }
  const off = t.get(TAG_OFFSET_TIME_ORIGINAL);
  let hasOffset = false;
  if (off) {
    const o = /^([+-])(\d{2}):(\d{2})/.exec(ascii(dv, off.valueOff, off.count));
    if (o) {
      const minutes = (+o[2] * 60 + +o[3]) * (o[1] === "-" ? -1 : 1);
      ms -= minutes * 60000;
      hasOffset = true;
    }
  }
  return { ms, hasOffset };
}

/** Capture time of a JPEG (APP1 Exif segment) or TIFF file from its first bytes, or null. */
export function exifCaptureTime(bytes: Uint8Array): ExifTime | null {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < 4) return null;
  if (bytes[0] === 0xff && bytes[1] === 0xd8) {
    let p = 2;
    while (p + 4 <= bytes.length) {
      if (bytes[p] !== 0xff) return null;
      const marker = bytes[p + 1];
      if (marker === 0xda || marker === 0xd9) return null; // image data: no EXIF before it
      const len = dv.getUint16(p + 2);
      if (marker === 0xe1 && p + 10 <= bytes.length && ascii(dv, p + 4, 4) === "Exif") {
        return timeFromTiff(dv, p + 10);
      }
      p += 2 + len;
    }
    return null;
  }
  if ((bytes[0] === 0x49 && bytes[1] === 0x49) || (bytes[0] === 0x4d && bytes[1] === 0x4d)) return timeFromTiff(dv, 0);
  return null;
}
