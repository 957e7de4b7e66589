import { describe, expect, it } from "vitest";
import { exifCaptureTime } from "../src/lib/exif";
import { classify, roleHintFromPath, sniffFile, uploadKindOf } from "../src/lib/sniff";
import { gpsWeekTowToMs, scanUbx, scanUbxInto, emptyUbxSummary } from "../src/lib/ubx";
import { blobOf, fixture } from "./helpers";

const sniff = (name: string, path = name) => sniffFile(blobOf(fixture(name)), path);

/** A UBX frame with a correct Fletcher checksum (u-blox interface description, section "UBX checksum"). */
function ubxFrame(cls: number, id: number, payload: Uint8Array): Uint8Array {
  const f = new Uint8Array(8 + payload.length);
  f.set([0xb5, 0x62, cls, id, payload.length & 0xff, payload.length >> 8]);
  f.set(payload, 6);
  let a = 0, b = 0;
  for (let i = 2; i < 6 + payload.length; i++) {
    a = (a + f[i]) & 0xff;
    b = (b + a) & 0xff;
  }
  f[6 + payload.length] = a;
  f[7 + payload.length] = b;
  return f;
}

function rawx(week: number, tow: number): Uint8Array {
  const p = new Uint8Array(16);
  const dv = new DataView(p.buffer);
  dv.setFloat64(0, tow, true);
  dv.setUint16(8, week, true);
  return ubxFrame(0x02, 0x15, p);
}

function concat(...parts: Uint8Array[]): Uint8Array {
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let o = 0;
  for (const p of parts) {
    out.set(p, o);
    o += p.length;
  }
  return out;
}

describe("file recognition by content", () => {
  it("recognises plain, gzip, .Z and Hatanaka observation files", async () => {
    for (const [name, hatanaka, compression] of [
      ["rover3.obs", false, "none"], ["base3.obs.gz", false, "gzip"], ["rover3.obs.Z", false, "compress"],
      ["trimble3.crx", true, "none"], ["base2.05d.Z", true, "compress"],
    ] as const) {
      const s = await sniff(name, `upload/${name}.bin`);
      expect(s.kind, name).toBe("rinex-obs");
      expect(s.hatanaka, name).toBe(hatanaka);
      expect(s.compression, name).toBe(compression);
    }
    const z = await sniff("rover3.obs.Z");
    expect(z.description).toBe("RINEX 3.04 observations, L1+L2+L7, Unix compress");
    expect(z.rinex!.firstObsMs).toBe(Date.parse("2024-06-24T08:10:18.200Z"));
  });

  it("tells navigation from observation files whatever their names", async () => {
    expect((await sniff("nav3.nav", "x/rover.obs")).kind).toBe("rinex-nav");
    expect((await sniff("nav2.05n", "data.txt")).kind).toBe("rinex-nav");
    expect((await sniff("base2.05o", "nav/some.nav")).kind).toBe("rinex-obs");
  });

  it("recognises JPEG photos and reads their EXIF capture time", async () => {
    const s = await sniff("img_head.jpg", "images/IMG_0001.JPG");
    expect(s.kind).toBe("image");
    expect(s.image!.format).toBe("jpeg");
    // PIL reads DateTimeOriginal 2024:06:24 08:10:34, SubSec 166, OffsetTimeOriginal +00:00
    expect(s.image!.capture).toEqual({ ms: Date.parse("2024-06-24T08:10:34.166Z"), hasOffset: true });
  });

  it("recognises TIFF by magic, both byte orders", () => {
    const le = new Uint8Array([0x49, 0x49, 0x2a, 0x00, 8, 0, 0, 0, 0, 0]);
    const be = new Uint8Array([0x4d, 0x4d, 0x00, 0x2a, 0, 0, 0, 8, 0, 0]);
    expect(classify("a.tif", le, le, "none").kind).toBe("image");
    expect(classify("b", be, be, "none").image!.format).toBe("tiff");
    expect(exifCaptureTime(le)).toBeNull();
  });

  it("recognises the points table, ODM gcp_list and the events table", async () => {
    const p = await sniff("points.csv", "x.txt");
    expect(p.kind).toBe("points");
    expect(p.points!.points.map((q) => q.role)).toEqual(["control", "control", "control", "check", "check"]);
    expect(p.description).toBe("ground points (3 control, 2 check)");
    const g = await sniff("gcp_list.txt");
    expect(g.kind).toBe("gcp-list");
    expect(g.gcpList!.crs).toBe("EPSG:32653");
    expect(g.gcpList!.measurements).toBeGreaterThan(10);
    const e = await sniff("events.csv", "photos.csv");
    expect(e.kind).toBe("events");
    expect(e.events!.count).toBe(12);
    expect(e.events!.images[0]).toBe("IMG_0001.JPG");
  });

  it("recognises u-blox UBX logs by a valid frame, and reads their time span", () => {
    const week = 2320;
    const log = concat(new Uint8Array([0, 1, 2]), rawx(week, 115800), ubxFrame(0x02, 0x13, new Uint8Array(12)), ubxFrame(0x0d, 0x03, new Uint8Array(28)), rawx(week, 115801.5));
    const s = classify("rover.ubx", log, log, "none");
    expect(s.kind).toBe("ubx");
    expect(s.ubx!.rawx).toBe(2);
    expect(s.ubx!.sfrbx).toBe(1);
    expect(s.ubx!.timTm2).toBe(1);
    expect(s.ubx!.firstMs).toBe(gpsWeekTowToMs(week, 115800));
    expect(s.ubx!.lastMs! - s.ubx!.firstMs!).toBe(1500);
    // 2024-06-24 is GPS week 2320, day 1 (Monday): tow 115800 s = 1 d 08:10:00 GPS time
    expect(new Date(gpsWeekTowToMs(week, 115800)).toISOString()).toBe("2024-06-24T08:10:00.000Z");
    // a corrupted checksum is not a frame
    const bad = rawx(week, 1);
    bad[bad.length - 1] ^= 0xff;
    expect(scanUbx(bad).frames).toBe(0);
    // streaming: a frame cut by the buffer end is left for the next piece
    const sum = emptyUbxSummary();
    const used = scanUbxInto(sum, log.subarray(0, log.length - 5));
    const rest = concat(log.subarray(used, log.length));
    scanUbxInto(sum, rest);
    expect(sum.rawx).toBe(2);
  });

  it("flags unsupported packings and leaves random binary unrecognised", () => {
    const bz = new TextEncoder().encode("BZh91AY&SY");
    expect(classify("a.bz2", bz, bz, "bzip2").problem).toMatch(/not supported/);
    const junk = new Uint8Array(512).map((_, i) => (i * 37) % 256);
    expect(classify("a.bin", junk, junk, "none").kind).toBe("unknown");
  });

  it("suggests rover/base from folder names and maps kinds to upload kinds", async () => {
    expect(roleHintFromPath("survey/rover/x.obs")).toBe("rover");
    expect(roleHintFromPath("Survey/Base/x.obs")).toBe("base");
    expect(roleHintFromPath("flight/drone_gnss.24o")).toBe("rover");
    expect(roleHintFromPath("x/database/x.obs")).toBeNull();
    const s = await sniff("rover3.obs", "survey/rover/rover.obs");
    expect(s.roleHint).toBe("rover"); // and the marker name ROVR agrees
    expect(uploadKindOf(s, "base")).toBe("base");
    expect(uploadKindOf((await sniff("nav3.nav")), null)).toBe("nav");
  });
});

describe("survey metadata", () => {
  it("recognises survey.json by its keys, not its name", () => {
    const enc = new TextEncoder();
    const j = enc.encode('{"project_crs": "EPSG:32653", "takeoff_antenna_ecef_m": [1, 2, 3]}');
    const s = classify("anything.txt", j, j, "none");
    expect(s.kind).toBe("survey-metadata");
    expect(s.description).toBe("survey metadata (EPSG:32653)");
    expect(uploadKindOf(s, null)).toBe("survey-metadata");
    const other = enc.encode('{"hello": 1}');
    expect(classify("survey.json", other, other, "none").kind).not.toBe("survey-metadata");
  });
});
