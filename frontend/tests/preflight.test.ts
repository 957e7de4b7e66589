import { describe, expect, it } from "vitest";
import { type CheckedFile, assignRoles, overlapS, preflight } from "../src/lib/preflight";
import { type Sniffed, sniffFile } from "../src/lib/sniff";
import { blobOf, fixture } from "./helpers";

const t = (s: string) => Date.parse(s + "Z");

function obs(path: string, first: string, last: string, events: number | null = 0, role: "rover" | "base" | null = null): CheckedFile {
  const sniff = {
    kind: "rinex-obs", compression: "none", hatanaka: false, description: "",
    rinex: { version: 3.04, type: "obs", firstObsMs: t(first), lastObsMs: t(last) },
  } as unknown as Sniffed;
  return { path, size: 1, sniff, role, scan: { epochs: 10, events, firstMs: t(first), lastMs: t(last) } };
}

const nav: CheckedFile = { path: "nav/x.nav", size: 1, role: null, sniff: { kind: "rinex-nav", compression: "none", hatanaka: false, description: "", navFirstMs: t("2024-06-24T06:00:00") } };
const img = (n: number, ms?: number): CheckedFile => ({
  path: `images/IMG_${String(n).padStart(4, "0")}.JPG`, size: 1, role: null,
  sniff: { kind: "image", compression: "none", hatanaka: false, description: "", image: { format: "jpeg", capture: ms ? { ms, hasOffset: true } : null } },
});
const codes = (p: { code: string }[]) => p.map((x) => x.code);

describe("pre-flight check", () => {
  it("passes a complete survey", () => {
    const files = [obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 3, "rover"),
      obs("base/b.obs", "2024-06-24T08:00:00", "2024-06-24T08:30:00", 0, "base"), nav, img(1), img(2), img(3)];
    const p = preflight(files);
    expect(p.filter((x) => x.severity !== "info")).toEqual([]);
  });

  it("reports missing navigation, rover and base", () => {
    expect(codes(preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0, "rover")]))).toContain("missing_nav");
    const p = preflight([nav]);
    expect(codes(p)).toEqual(expect.arrayContaining(["missing_rover", "missing_base"]));
    expect(p.every((x, i) => i === 0 || ["error", "warning", "info"].indexOf(p[i - 1].severity) <= ["error", "warning", "info"].indexOf(x.severity))).toBe(true);
  });

  it("finds no overlap between rover and base times, with the times in the message", () => {
    const p = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0, "rover"),
      obs("base/b.obs", "2024-06-23T08:00:00", "2024-06-23T09:00:00", 0, "base"), nav]);
    const e = p.find((x) => x.code === "no_overlap")!;
    expect(e.severity).toBe("error");
    expect(e.message).toContain("2024-06-24 08:10:00");
    expect(e.message).toContain("2024-06-23 09:00:00");
  });

  it("warns when the base covers only part of the flight", () => {
    const p = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0, "rover"),
      obs("base/b.obs", "2024-06-24T08:15:00", "2024-06-24T09:00:00", 0, "base"), nav]);
    const w = p.find((x) => x.code === "partial_overlap")!;
    expect(w.message).toContain("50 %");
    expect(w.message).toContain("5 min missing at the start");
    expect(overlapS({ firstMs: 0, lastMs: 10000 }, { firstMs: 5000, lastMs: 20000 })).toBe(5);
  });

  it("warns about images without camera events", () => {
    const base = obs("base/b.obs", "2024-06-24T08:00:00", "2024-06-24T08:30:00", 0, "base");
    const noEvents = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0, "rover"), base, nav, img(1), img(2)]);
    expect(codes(noEvents)).toContain("images_without_events");
    const few = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 1, "rover"), base, nav, img(1), img(2), img(3)]);
    expect(few.find((x) => x.code === "images_without_events")!.message).toContain("only 1 camera events");
    const table: CheckedFile = { path: "events.csv", size: 1, role: null, sniff: { kind: "events", compression: "none", hatanaka: false, description: "", events: { images: ["IMG_0001.JPG"], count: 1, errors: [] } } };
    const listed = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", null, "rover"), base, nav, table, img(1), img(2)]);
    expect(listed.find((x) => x.code === "images_without_events")!.files).toEqual(["images/IMG_0002.JPG"]);
  });

  it("warns about photos taken outside the flight (EXIF clock)", () => {
    const p = preflight([obs("rover/r.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 2, "rover"),
      obs("base/b.obs", "2024-06-24T08:00:00", "2024-06-24T08:30:00", 0, "base"), nav,
      img(1, t("2024-06-24T08:12:00")), img(2, t("2024-06-25T08:12:00"))]);
    expect(p.find((x) => x.code === "images_outside_flight")!.files).toEqual(["images/IMG_0002.JPG"]);
  });

  it("runs on the real fixture files: roles from folders, nav and points recognised", async () => {
    const files: CheckedFile[] = [];
    for (const [name, path] of [["rover3.obs", "s/rover/rover.obs"], ["base3.obs", "s/base/base.obs"], ["nav3.nav", "s/nav/base.nav"], ["points.csv", "s/gcp/points.csv"]]) {
      const f = fixture(name);
      files.push({ path, size: f.length, sniff: await sniffFile(blobOf(f), path), role: null });
    }
    assignRoles(files);
    expect(files.map((f) => f.role)).toEqual(["rover", "base", null, null]);
    const p = preflight(files);
    expect(p.filter((x) => x.severity === "error")).toEqual([]);
  });

  it("assigns roles without folder names: the file with events / the shorter span is the rover", () => {
    const a = obs("x/a.obs", "2024-06-24T08:00:00", "2024-06-24T09:00:00", 0);
    const b = obs("x/b.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0);
    assignRoles([a, b]);
    expect([a.role, b.role]).toEqual(["base", "rover"]);
    const c = obs("x/c.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 0);
    const d = obs("x/d.obs", "2024-06-24T08:10:00", "2024-06-24T08:20:00", 4);
    assignRoles([c, d]);
    expect([c.role, d.role]).toEqual(["base", "rover"]);
  });
});
