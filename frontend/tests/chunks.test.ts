import { describe, expect, it } from "vitest";
import { backoffMs, contentRange, planChunks } from "../src/lib/chunks";

describe("upload chunks", () => {
  it("covers the file exactly from the resume offset", () => {
    const size = 20 * 1024 * 1024 + 5;
    const chunks = planChunks(size, 3 * 1024 * 1024, 8 * 1024 * 1024);
    expect(chunks[0].start).toBe(3 * 1024 * 1024);
    for (let i = 1; i < chunks.length; i++) expect(chunks[i].start).toBe(chunks[i - 1].end);
    expect(chunks[chunks.length - 1].end).toBe(size);
    expect(chunks.every((c) => c.end - c.start <= 8 * 1024 * 1024 && c.end > c.start)).toBe(true);
  });

  it("has nothing left when everything was received, and refuses impossible offsets", () => {
    expect(planChunks(100, 100)).toEqual([]);
    expect(planChunks(0, 0)).toEqual([]);
    expect(() => planChunks(100, 101)).toThrow();
    expect(() => planChunks(100, -1)).toThrow();
  });

  it("writes Content-Range with an inclusive end", () => {
    expect(contentRange({ start: 0, end: 10 }, 25)).toBe("bytes 0-9/25");
    expect(contentRange({ start: 20, end: 25 }, 25)).toBe("bytes 20-24/25");
    expect(() => contentRange({ start: 5, end: 5 }, 25)).toThrow();
  });

  it("backs off exponentially up to a cap", () => {
    expect([0, 1, 2, 3].map((a) => backoffMs(a))).toEqual([1000, 2000, 4000, 8000]);
    expect(backoffMs(20)).toBe(30000);
  });
});
