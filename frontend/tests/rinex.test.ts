import { describe, expect, it } from "vitest";
import {
  EpochScanner, calendarMs, firstNavRecordMs, lastEpochIn, parseEpochLine, parseRinexHeader, parseTimeOfObs, phaseBands,
} from "../src/lib/rinexHeader";
import { fixtureText } from "./helpers";

const utc = (s: string) => Date.parse(s + "Z");

describe("RINEX header", () => {
  it("reads a RINEX 3 observation header (simulated rover)", () => {
    const h = parseRinexHeader(fixtureText("rover3.obs"))!;
    expect(h.type).toBe("obs");
    expect(h.version).toBeCloseTo(3.04, 6);
    expect(h.system).toBe("M");
    expect(h.markerName).toBe("ROVR");
    expect(h.intervalS).toBeCloseTo(0.2, 9);
    expect(h.firstObsMs).toBe(utc("2024-06-24T08:10:18.200"));
    expect(h.lastObsMs).toBe(utc("2024-06-24T08:12:06.200"));
    expect(h.timeSystem).toBe("GPS");
    expect(h.obsTypes.G).toEqual(["C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "D2W", "S2W"]);
    expect(phaseBands(h)).toEqual(["L1", "L2", "L7"]);
    expect(h.approxPositionEcefM![0]).toBeCloseTo(-3817427.9152, 4);
    expect(h.headerLength).toBeGreaterThan(1000);
  });

  it("reads a RINEX 2.10 header without TIME OF LAST OBS", () => {
    const h = parseRinexHeader(fixtureText("base2.05o"))!;
    expect(h.type).toBe("obs");
    expect(h.version).toBeCloseTo(2.1, 6);
    expect(h.obsTypes["*"]).toEqual(["L1", "C1", "L2", "P2"]);
    expect(h.firstObsMs).toBe(utc("2005-04-02T00:00:00"));
    expect(h.lastObsMs).toBeNull();
    expect(h.intervalS).toBe(30);
  });

  it("reads the clear-text header inside Hatanaka CRINEX 1 and 3", () => {
    const a = parseRinexHeader(fixtureText("trimble3.crx"))!;
    expect(a.hatanaka).toBe(true);
    expect(a.type).toBe("obs");
    expect(a.version).toBeCloseTo(3.04, 6);
    expect(a.receiver).toBe("TRIMBLE NetR9");
    const b = parseRinexHeader(fixtureText("base2.05d"))!;
    expect(b.hatanaka).toBe(true);
    expect(b.firstObsMs).toBe(utc("2005-04-02T00:00:00"));
  });

  it("recognises navigation files and reads their first record time", () => {
    const n3 = fixtureText("nav3.nav");
    const h3 = parseRinexHeader(n3)!;
    expect(h3.type).toBe("nav");
    expect(firstNavRecordMs(n3, h3.version)).not.toBeNull();
    const n2 = fixtureText("nav2.05n");
    const h2 = parseRinexHeader(n2)!;
    expect(h2.type).toBe("nav");
    const t2 = firstNavRecordMs(n2, h2.version)!;
    // GEONET 0759, 2005-04-02 (day 092): broadcast records of that day
    expect(new Date(t2).toISOString().slice(0, 10)).toBe("2005-04-02");
  });

  it("rejects what is not RINEX", () => {
    expect(parseRinexHeader("name,easting_m\nA,1\n")).toBeNull();
    expect(parseRinexHeader("")).toBeNull();
  });

  it("parses TIME OF FIRST OBS fields, including fractional seconds and 2-digit years", () => {
    const v = parseTimeOfObs("  2024     6    24     8    10   18.2000000     GPS         TIME OF FIRST OBS")!;
    expect(v.ms).toBe(utc("2024-06-24T08:10:18.200"));
    expect(v.system).toBe("GPS");
    expect(parseTimeOfObs("  2024    13    24     8    10   18.2000000     GPS         TIME OF FIRST OBS")).toBeNull();
    expect(calendarMs(5, 4, 2, 0, 0, 0)).toBe(utc("2005-04-02T00:00:00"));
    expect(calendarMs(99, 1, 1, 0, 0, 0)).toBe(utc("1999-01-01T00:00:00"));
  });

  it("parses epoch lines of RINEX 2 and 3 with their flags", () => {
    expect(parseEpochLine("> 2024 06 24 08 10 52.1286254  5  0", 3)).toEqual({ ms: utc("2024-06-24T08:10:52.129"), flag: 5 });
    expect(parseEpochLine(" 05  4  2  0  0  0.0000000  0  8G 3G 7G 8G11G19G20G24G28", 2)).toEqual({ ms: utc("2005-04-02T00:00:00"), flag: 0 });
    expect(parseEpochLine("  55923622.160    24767686.375    43647388.2424   24767684.8224", 2)).toBeNull();
    expect(lastEpochIn(fixtureText("base2.05o"), 2)).toBe(utc("2005-04-02T00:09:30.001")) // the receiver wrote 30.0010000;
  });

  it("counts epochs and camera events in a stream cut at arbitrary places", () => {
    const text = fixtureText("rover3_events.obs");
    for (const piece of [7, 100, 4096, text.length]) {
      const s = new EpochScanner(3);
      for (let i = 0; i < text.length; i += piece) s.push(text.slice(i, i + piece));
      s.finish();
      expect(s.events).toBe(2);
      expect(s.epochs).toBe(13);
      expect(s.firstMs).toBe(utc("2024-06-24T08:10:51.800"));
      expect(s.lastMs).toBe(utc("2024-06-24T08:10:54.200"));
    }
  });
});
