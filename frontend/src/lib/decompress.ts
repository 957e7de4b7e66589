/**
 * Just enough decompression to look inside compressed survey files: gzip (the browser's
 * DecompressionStream) and Unix compress .Z (LZW, implemented here: browsers have no decoder).
 * Only the first bytes are needed for recognition, so both stop after `maxOut` output bytes.
 */

export type Compression = "none" | "gzip" | "compress" | "zip" | "bzip2" | "xz" | "zstd";

export function detectCompression(b: Uint8Array): Compression {
  if (b.length >= 2 && b[0] === 0x1f && b[1] === 0x8b) return "gzip";
  if (b.length >= 2 && b[0] === 0x1f && b[1] === 0x9d) return "compress";
  if (b.length >= 4 && b[0] === 0x50 && b[1] === 0x4b && b[2] === 0x03 && b[3] === 0x04) return "zip";
  if (b.length >= 3 && b[0] === 0x42 && b[1] === 0x5a && b[2] === 0x68) return "bzip2";
  if (b.length >= 6 && b[0] === 0xfd && b[1] === 0x37 && b[2] === 0x7a && b[3] === 0x58 && b[4] === 0x5a) return "xz";
  if (b.length >= 4 && b[0] === 0x28 && b[1] === 0xb5 && b[2] === 0x2f && b[3] === 0xfd) return "zstd";
  return "none";
}

/**
 * Decode Unix `compress` (.Z) data: LZW with 9..maxbits-bit codes, block mode (code 256 = clear).
 * Stops after maxOut bytes. A truncated input gives what could be decoded.
 */
export function decodeLzw(input: Uint8Array, maxOut = 1 << 20): Uint8Array {
  if (input.length < 3 || input[0] !== 0x1f || input[1] !== 0x9d) throw new Error("not compress (.Z) data");
  const maxBits = input[2] & 0x1f;
  const blockMode = (input[2] & 0x80) !== 0;
  if (maxBits < 9 || maxBits > 16) throw new Error(`compress: bad max bits ${maxBits}`);
  const maxCodes = 1 << maxBits;
  const prefix = new Int32Array(maxCodes);
  const suffix = new Uint8Array(maxCodes);
  for (let c = 0; c < 256; c++) suffix[c] = c;
  const stack = new Uint8Array(maxCodes);
  const out = new Uint8Array(maxOut);
  let outLen = 0;

  let nBits = 9;
  let free = blockMode ? 257 : 256;
  let maxCode = (1 << nBits) - 1;
  // Codes are read in groups of 8 (nBits bytes); on a width change or clear the rest of the group
  // is skipped: this is how compress(1) writes them.
  let bitPos = 3 * 8;
  let groupStart = bitPos;
  const totalBits = input.length * 8;
  let old = -1;
  let finChar = 0;

  const readCode = (): number => {
    if (bitPos + nBits > totalBits) return -1;
    const byte = bitPos >> 3;
    const shift = bitPos & 7;
    const v = (input[byte] | ((input[byte + 1] ?? 0) << 8) | ((input[byte + 2] ?? 0) << 16)) >>> shift;
    bitPos += nBits;
    return v & ((1 << nBits) - 1);
  };
  const skipToGroupEnd = () => {
    const groupBits = nBits * 8;
    const used = bitPos - groupStart;
    const rem = used % groupBits;
    if (rem !== 0) bitPos += groupBits - rem;
  };

  while (outLen < maxOut) {
    if (free > maxCode && nBits < maxBits) {
      skipToGroupEnd();
      nBits++;
      maxCode = nBits === maxBits ? maxCodes - 1 : (1 << nBits) - 1;
      groupStart = bitPos;
    }
    const code = readCode();
    if (code < 0) break;
    if (old === -1) {
      if (code > 255) throw new Error("compress: corrupt data (first code)");
      old = code;
      finChar = code;
      out[outLen++] = code;
      continue;
    }
    if (code === 256 && blockMode) {
      skipToGroupEnd();
      nBits = 9;
      maxCode = (1 << nBits) - 1;
      free = 256; // the next free entry after the increment below is 257
      groupStart = bitPos;
      old = -1;
      // The first code after a clear is a literal; mimic by reading it directly.
      const c = readCode();
      if (c < 0) break;
      free = 257;
      old = c;
      finChar = c;
      out[outLen++] = c;
      continue;
    }
    let sp = 0;
    let cur = code;
    if (cur >= free) {
      if (cur > free) throw new Error("compress: corrupt data (code out of range)");
      stack[sp++] = finChar;
      cur = old;
    }
    while (cur >= 256) {
      stack[sp++] = suffix[cur];
      cur = prefix[cur];
    }
    finChar = suffix[cur];
    stack[sp++] = finChar;
    while (sp > 0 && outLen < maxOut) out[outLen++] = stack[--sp];
    if (free < maxCodes) {
      prefix[free] = old;
      suffix[free] = finChar;
      free++;
    }
    old = code;
  }
  return out.slice(0, outLen);
}

/** Decompress the start of a gzip member with the platform's DecompressionStream (browser and Node 18+). */
export async function gunzipHead(input: Uint8Array, maxOut = 1 << 20): Promise<Uint8Array> {
  const ds = new DecompressionStream("gzip");
  const writer = ds.writable.getWriter();
  const reader = ds.readable.getReader();
  writer.write(input as Uint8Array<ArrayBuffer>).catch(() => undefined);
  writer.close().catch(() => undefined);
  const parts: Uint8Array[] = [];
  let n = 0;
  try {
    while (n < maxOut) {
      const { value, done } = await reader.read();
      if (done) break;
      parts.push(value);
      n += value.length;
    }
  } catch {
    // A truncated stream ends with an error after the decodable part: keep what came out.
  } finally {
    reader.cancel().catch(() => undefined);
  }
  const out = new Uint8Array(Math.min(n, maxOut));
  let off = 0;
  for (const p of parts) {
    const take = Math.min(p.length, out.length - off);
    out.set(p.subarray(0, take), off);
    off += take;
    if (off >= out.length) break;
  }
  return out;
}

/** The first (up to maxOut) decompressed bytes of `head` (the start of a file), and its compression. */
export async function inflateHead(head: Uint8Array, maxOut = 1 << 20): Promise<{ compression: Compression; data: Uint8Array }> {
  const compression = detectCompression(head);
  try {
    if (compression === "gzip") return { compression, data: await gunzipHead(head, maxOut) };
    if (compression === "compress") return { compression, data: decodeLzw(head, maxOut) };
  } catch {
    return { compression, data: new Uint8Array(0) };
  }
  return { compression, data: head };
}
