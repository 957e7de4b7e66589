/**
 * Whole-file scan of a rover observation file in the browser, streaming (memory stays bounded): the
 * first and last epochs and the camera event records (RINEX epoch flag 5, UBX TIM-TM2). Plain and gzip
 * files are scanned; Hatanaka-compressed epochs are differential text, so only the header times are used.
 */

import type { Compression } from "./decompress";
import { decodeLzw } from "./decompress";
import { EpochScanner } from "./rinexHeader";
import type { Sniffed } from "./sniff";
import { emptyUbxSummary, scanUbxInto } from "./ubx";

export interface ObsScan {
  epochs: number | null;
  events: number | null;
  firstMs: number | null;
  lastMs: number | null;
  /** Why the scan could not count events, when it could not. */
  note?: string;
}

async function* byteStream(file: Blob, compression: Compression, signal?: AbortSignal): AsyncGenerator<Uint8Array> {
  if (compression === "compress") {
    // No streaming LZW here: decode up to 512 MB in one go (a .Z rover file is rarely over 100 MB).
    const all = new Uint8Array(await file.arrayBuffer());
    yield decodeLzw(all, 512 * 1024 * 1024);
    return;
  }
  let stream: ReadableStream<Uint8Array> = file.stream() as ReadableStream<Uint8Array>;
  if (compression === "gzip") stream = stream.pipeThrough(new DecompressionStream("gzip") as unknown as TransformStream<Uint8Array, Uint8Array>);
  const reader = stream.getReader();
  try {
    for (;;) {
      if (signal?.aborted) throw new DOMException("scan aborted", "AbortError");
      const { value, done } = await reader.read();
      if (done) return;
      yield value;
    }
  } finally {
    reader.cancel().catch(() => undefined);
  }
}

export async function scanObservationFile(file: Blob, s: Sniffed, signal?: AbortSignal): Promise<ObsScan> {
  if (s.kind === "rinex-obs" && s.rinex) {
    if (s.hatanaka) {
      return {
        epochs: null, events: null, firstMs: s.rinex.firstObsMs, lastMs: s.rinex.lastObsMs,
        note: "Hatanaka-compressed: camera events are counted on the server",
      };
    }
    const scanner = new EpochScanner(s.rinex.version);
    const dec = new TextDecoder("latin1");
    for await (const piece of byteStream(file, s.compression, signal)) scanner.push(dec.decode(piece, { stream: true }));
    scanner.finish();
    return { epochs: scanner.epochs, events: scanner.events, firstMs: scanner.firstMs ?? s.rinex.firstObsMs, lastMs: scanner.lastMs ?? s.rinex.lastObsMs };
  }
  if (s.kind === "ubx") {
    const sum = emptyUbxSummary();
    let carry = new Uint8Array(0);
    for await (const piece of byteStream(file, s.compression, signal)) {
      const buf = carry.length ? concat(carry, piece) : piece;
      const used = scanUbxInto(sum, buf);
      carry = buf.slice(used);
    }
    return { epochs: sum.rawx, events: sum.timTm2, firstMs: sum.firstMs, lastMs: sum.lastMs };
  }
  return { epochs: null, events: null, firstMs: null, lastMs: null, note: "not an observation file" };
}

function concat(a: Uint8Array, b: Uint8Array): Uint8Array {
  const out = new Uint8Array(a.length + b.length);
  out.set(a, 0);
  out.set(b, a.length);
  return out;
}
