import { describe, expect, it } from "vitest";
import { decodeLzw, detectCompression, gunzipHead, inflateHead } from "../src/lib/decompress";
import { fixture } from "./helpers";

describe("decompression of file heads", () => {
  it("recognises packings by their magic bytes", () => {
    expect(detectCompression(fixture("base3.obs.gz"))).toBe("gzip");
    expect(detectCompression(fixture("rover3.obs.Z"))).toBe("compress");
    expect(detectCompression(fixture("rover3.obs"))).toBe("none");
    expect(detectCompression(new Uint8Array([0x50, 0x4b, 0x03, 0x04, 0]))).toBe("zip");
    expect(detectCompression(new TextEncoder().encode("BZh91AY"))).toBe("bzip2");
  });

  it("decodes Unix compress (.Z) made by ncompress, byte for byte", () => {
    expect(decodeLzw(fixture("rover3.obs.Z"))).toEqual(fixture("rover3.obs"));
    expect(decodeLzw(fixture("base2.05d.Z"))).toEqual(fixture("base2.05d"));
  });

  it("stops .Z decoding at the requested size and survives truncated input", () => {
    const full = fixture("rover3.obs");
    expect(decodeLzw(fixture("rover3.obs.Z"), 1000)).toEqual(full.subarray(0, 1000));
    const cut = decodeLzw(fixture("rover3.obs.Z").subarray(0, 5000));
    expect(cut.length).toBeGreaterThan(5000);
    expect(cut).toEqual(full.subarray(0, cut.length));
  });

  it("gunzips whole and truncated gzip heads", async () => {
    const full = fixture("base3.obs");
    expect(await gunzipHead(fixture("base3.obs.gz"))).toEqual(full);
    const part = await gunzipHead(fixture("base3.obs.gz").subarray(0, 3000));
    expect(part.length).toBeGreaterThan(3000);
    expect(part).toEqual(full.subarray(0, part.length));
    const { compression, data } = await inflateHead(fixture("base3.obs.gz"), 100);
    expect(compression).toBe("gzip");
    expect(data).toEqual(full.subarray(0, 100));
  });
});
