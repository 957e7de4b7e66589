import { createHash } from "node:crypto";
import { describe, expect, it } from "vitest";
import { Sha256, WEBCRYPTO_MAX_BYTES, sha256Fast, sha256OfBlob } from "../src/lib/sha256";
import { blobOf } from "./helpers";

const nodeHex = (b: Uint8Array) => createHash("sha256").update(b).digest("hex");

function pseudoRandom(n: number, seed = 7): Uint8Array {
  const out = new Uint8Array(n);
  let x = seed >>> 0;
  for (let i = 0; i < n; i++) {
    x = (Math.imul(x, 1664525) + 1013904223) >>> 0;
    out[i] = x >>> 24;
  }
  return out;
}

describe("Sha256", () => {
  it("matches the FIPS 180-4 test vectors", () => {
    const enc = new TextEncoder();
    expect(new Sha256().update(enc.encode("abc")).hex()).toBe("ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    expect(new Sha256().hex()).toBe("e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    expect(new Sha256().update(enc.encode("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq")).hex())
      .toBe("248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  });

  it("gives the same digest whatever the chunking (lengths around the 55/56/64-byte padding edges)", () => {
    const data = pseudoRandom(4099);
    for (const n of [0, 1, 55, 56, 57, 63, 64, 65, 119, 120, 128, 1000, 4099]) {
      const part = data.subarray(0, n);
      const want = nodeHex(part);
      expect(new Sha256().update(part).hex()).toBe(want);
      for (const step of [1, 3, 63, 64, 65, 1000]) {
        const h = new Sha256();
        for (let i = 0; i < n; i += step) h.update(part.subarray(i, Math.min(n, i + step)));
        expect(h.hex(), `n=${n} step=${step}`).toBe(want);
      }
    }
  });

  it("hashes a blob read in slices, reporting progress", async () => {
    const data = pseudoRandom(1_000_003, 11);
    const seen: number[] = [];
    const hex = await sha256OfBlob(blobOf(data), (d) => seen.push(d), undefined, 65536);
    expect(hex).toBe(nodeHex(data));
    expect(seen[seen.length - 1]).toBe(data.length);
    expect(seen.length).toBe(Math.ceil(data.length / 65536));
  });

  it("refuses updates after the digest", () => {
    const h = new Sha256();
    h.digest();
    expect(() => h.update(new Uint8Array(1))).toThrow();
  });
});

describe("sha256Fast", () => {
  it("gives the same digest through WebCrypto (small files) and the incremental path (large files)", async () => {
    const data = pseudoRandom(300_001, 5);
    expect(await sha256Fast(blobOf(data))).toBe(nodeHex(data));
    const big = { size: WEBCRYPTO_MAX_BYTES + 1, slice: (a: number, b: number) => blobOf(data.subarray(Math.min(a, data.length), Math.min(b, data.length))) };
    // a fake "large" blob whose slices past the data are empty: the incremental path reads it in slices
    const seen: number[] = [];
    await sha256Fast(big as unknown as Blob, (n) => seen.push(n));
    expect(seen.length).toBeGreaterThan(1);
  });
});
