import { existsSync, readFileSync } from "node:fs";
import { describe, expect, it } from "vitest";
import { looksLikeMrk, parseMrk } from "../src/lib/mrk";
import { type CheckedFile, assignRoles, markFlights, preflight, summarise } from "../src/lib/preflight";
import { crc24q, scanRtcm3 } from "../src/lib/rtcm3";
import { classify, uploadKindOf } from "../src/lib/sniff";

const REAL = "/work/shared/data/dji/p4rtk_auckland_2018";

/** Bits (value, width) packed big-endian, padded with zeros to `size` bytes. */
function bits(fields: [number, number][], size = 0): Uint8Array {
  let s = fields.map(([v, n]) => (BigInt(v) & ((1n << BigInt(n)) - 1n)).toString(2).padStart(n, "0")).join("");
  s += "0".repeat((8 - (s.length % 8)) % 8);
  const out = new Uint8Array(Math.max(size, s.length / 8));
  for (let i = 0; i < s.length / 8; i++) out[i] = parseInt(s.slice(8 * i, 8 * i + 8), 2);
  return out;
}

function frame(payload: Uint8Array): Uint8Array {
  const f = new Uint8Array(payload.length + 6);
  f.set([0xd3, payload.length >> 8, payload.length & 0xff]);
  f.set(payload, 3);
  const crc = crc24q(f, 0, payload.length + 3);
  f.set([crc >> 16, (crc >> 8) & 0xff, crc & 0xff], payload.length + 3);
  return f;
}

const msm4 = (towMs: number) => frame(bits([[1074, 12], [0, 12], [towMs, 30], [0, 1], [0, 3], [0, 7], [0, 2], [0, 2], [0, 1], [0, 3],
  [2 ** 59, 64], [2 ** 30, 32], [1, 1], [70, 8], [512, 10], [100, 15], [200, 22], [9, 4], [0, 1], [45, 6]]));
const eph1019 = (sat: number) => frame(bits([[1019, 12], [sat, 6], [1000, 10]], 61));

function concat(parts: Uint8Array[]): Uint8Array {
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let o = 0;
  for (const p of parts) {
    out.set(p, o);
    o += p.length;
  }
  return out;
}

function ppkraw(sow: number, seconds: number, ephSats: number): Uint8Array {
  const parts: Uint8Array[] = [];
  for (let s = 1; s <= ephSats; s++) parts.push(eph1019(s));
  for (let k = 0; k <= seconds; k++) parts.push(msm4((sow + k) * 1000), new Uint8Array([0x55, 0xaa, 1, 2]));
  return concat(parts);
}

function mrk(n: number, sow: number): string {
  return Array.from({ length: n }, (_, i) => `${i + 1}\t${(sow + 3 * i).toFixed(6)}\t[2024]\t   -26,N\t    19,E\t   191,V\t-36.41144502,Lat\t174.63075195,Lon\t170.415,Ellh\t0.012, 0.011, 0.025\t50,Q`).join("\n") + "\n";
}

const enc = new TextEncoder();
const JPEG = new Uint8Array([0xff, 0xd8, 0xff, 0xe0, 0, 16, 0x4a, 0x46, 0x49, 0x46, 0, 1, 1, 0, 0, 1, 0, 1, 0, 0]);

function file(path: string, data: Uint8Array): CheckedFile {
  return { path, size: data.length, role: null, sniff: classify(path, data, data, "none") };
}

function rinexObs(marker: string): Uint8Array {
  const head = [
    `${"3.04".padStart(9)}${"".padEnd(11)}${"OBSERVATION DATA".padEnd(20)}${"G (GPS)".padEnd(20)}RINEX VERSION / TYPE`,
    `${marker.padEnd(60)}MARKER NAME`,
    `${"".padEnd(60)}END OF HEADER`,
  ];
  return enc.encode(head.join("\n") + "\n");
}

function flightFiles(folder: string, photos: number, exposures: number, sow: number, ephSats = 6): CheckedFile[] {
  const name = folder.split("/").pop()!;
  const out = Array.from({ length: photos }, (_, i) => file(`${folder}/DJI_${String(i + 1).padStart(4, "0")}.JPG`, JPEG));
  out.push(file(`${folder}/${name}_Timestamp.MRK`, enc.encode(mrk(exposures, sow))));
  out.push(file(`${folder}/${name}_PPKRAW.bin`, ppkraw(sow - 10, 30, ephSats)));
  out.push(file(`${folder}/${name}_EVENTLOG.bin`, new Uint8Array(Array.from({ length: 512 }, (_, i) => i % 256))));
  return out;
}

describe("RTCM 3 logs", () => {
  it("scans frames: messages, systems, ephemerides, epoch times", () => {
    const s = scanRtcm3(ppkraw(300000, 20, 5));
    expect(s.frames).toBe(26);
    expect(s.messages[1074]).toBe(21);
    expect(s.systems).toEqual(["G"]);
    expect(s.ephemerisSatellites).toEqual({ G: 5 });
    expect(s.firstTowMs).toBe(299990000 + 10000);
    expect(s.lastTowMs).toBe(300020000);
  });

  it("is recognised by content whatever its name, and is an observation file with a role", () => {
    const f = file("DCIM/100_0004/100_0004_PPKRAW.bin", ppkraw(300000, 20, 0));
    expect(f.sniff.kind).toBe("rtcm3");
    expect(f.sniff.description).toBe("RTCM 3 log, G");
    expect(uploadKindOf(f.sniff, "base")).toBe("base");
    const corrupt = ppkraw(300000, 20, 0).map((b, i) => (i % 37 === 5 ? b ^ 0x10 : b));
    expect(classify("x.bin", corrupt, corrupt, "none").kind).toBe("unknown");
  });

  it.skipIf(!existsSync(`${REAL}/100_0004_PPKRAW.bin`))("reads the head of a real Phantom 4 RTK PPKRAW.bin", () => {
    const head = new Uint8Array(readFileSync(`${REAL}/100_0004_PPKRAW.bin`)).subarray(0, 64 * 1024);
    const s = classify("100_0004_PPKRAW.bin", head, head, "none");
    expect(s.kind).toBe("rtcm3");
    expect(s.rtcm3!.systems).toEqual(["G", "R", "E", "C"]);
    expect(s.rtcm3!.firstTowMs).toBe(275287600);
  });
});

describe("DJI Timestamp.MRK", () => {
  it("is recognised by its first line and counted", () => {
    const text = mrk(5, 300000);
    expect(looksLikeMrk(text)).toBe(true);
    expect(looksLikeMrk("name,easting_m\n")).toBe(false);
    const m = parseMrk(text);
    expect([m.exposures, m.firstIndex, m.lastIndex]).toEqual([5, 1, 5]);
    expect(new Date(m.firstMs!).toISOString()).toBe("2018-10-24T11:20:00.000Z");
    const f = file("a/x_Timestamp.MRK", enc.encode(text));
    expect(f.sniff.kind).toBe("dji-mrk");
    expect(uploadKindOf(f.sniff, null)).toBe("flight");
    const bad = file("a/x_Timestamp.MRK", enc.encode(text.replace("3\t300006", "3\tabc")));
    expect(bad.sniff.problem).toContain("line 3");
  });

  it.skipIf(!existsSync(`${REAL}/100_0004_Timestamp.MRK`))("counts a real MRK", () => {
    expect(parseMrk(readFileSync(`${REAL}/100_0004_Timestamp.MRK`, "latin1")).exposures).toBe(163);
  });
});

describe("DJI flight folders in the pre-check", () => {
  it("accepts a drop of two flights and three base files, and names what it found", () => {
    const files = [...flightFiles("DCIM/100_0004", 2, 2, 300000), ...flightFiles("DCIM/100_0005", 2, 2, 300600),
      file("base/a.obs", rinexObs("AUCK")), file("cors/b.obs", rinexObs("AUCK")), file("cors/c.obs", rinexObs("AUCK"))];
    expect(markFlights(files)).toEqual(["DCIM/100_0004", "DCIM/100_0005"]);
    assignRoles(files);
    const log = files.find((f) => f.path.endsWith("100_0004_PPKRAW.bin"))!;
    expect([log.flight, log.role]).toEqual(["DCIM/100_0004", "rover"]);
    expect(files.find((f) => f.path.endsWith("EVENTLOG.bin"))!.flight).toBeNull();
    expect(files.filter((f) => f.path.endsWith(".obs")).map((f) => f.role)).toEqual(["base", "base", "base"]);
    const p = preflight(files);
    expect(p.filter((x) => x.severity === "error")).toEqual([]);
    expect(p.map((x) => x.code)).toEqual(expect.arrayContaining(["rovers_joined", "bases_joined", "nav_from_rtcm3"]));
    expect(p.map((x) => x.code)).not.toContain("images_without_events");
    expect(summarise(files)).toBe("2 flights, 4 photos, MRK 4 exposures, 2 RTCM 3 rover logs, base: 3 RINEX files, no navigation file needed");
  });

  it("takes RTK-tagged photos without a raw log or base as photo positions only, not as an error", () => {
    const files = flightFiles("DCIM/100_0007", 3, 3, 300000).filter((f) => !f.path.endsWith(".bin"));
    markFlights(files);
    const p = preflight(files);
    expect(p.filter((x) => x.severity === "error")).toEqual([]);
    expect(p.map((x) => x.code)).toContain("photos_only");
    expect(summarise(files)).toBe("1 flight, 3 photos, MRK 3 exposures, no rover log, no base, photo positions only (no PPK)");
  });

  it("warns about a PPKRAW without ephemerides (the server reads it whole) and exposures that do not match the photos", () => {
    const files = [...flightFiles("F", 3, 4, 300000, 0), file("base/a.obs", rinexObs("BASE"))];
    markFlights(files);
    assignRoles(files);
    const p = preflight(files);
    const codes = Object.fromEntries(p.map((x) => [x.code, x]));
    expect(codes.nav_unknown.severity).toBe("warning");
    expect(codes.nav_unknown.message).toContain("F_PPKRAW.bin");
    expect(codes.missing_nav).toBeUndefined();
    expect(codes.mrk_photos.message).toBe("F/F_Timestamp.MRK: 4 exposures but 3 photos in F (deleted photos?).");
    expect(summarise(files)).toBe("1 flight, 3 photos, MRK 4 exposures, RTCM 3 rover log, base: 1 RINEX file, no navigation file");
  });
});
