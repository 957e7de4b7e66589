import { describe, expect, it } from "vitest";
import served from "./fixtures/file_kinds.json";
import { FLIGHT_KINDS, OBSERVATION_KINDS, SERVER_KINDS, UPLOAD_KINDS } from "../src/lib/sniff";

// frontend/tests/fixtures/file_kinds.json is GET /file-kinds (tests/frontend/test_file_kind_names.py keeps it
// fresh): the pre-check names files with the server's words, and asks for the hints the server accepts
describe("file kind names are the server's", () => {
  it("kinds recognised by content", () => {
    expect([...SERVER_KINDS].sort()).toEqual(served.kinds.map((k) => k.name).sort());
  });
  it("upload hints", () => {
    const hints = Object.keys(served.hints).filter((h) => h !== "image");   // "image": a synonym of "images"
    expect([...UPLOAD_KINDS].sort()).toEqual(hints.sort());
  });
  it("observation and flight kinds", () => {
    expect([...OBSERVATION_KINDS].sort()).toEqual([...served.observation_kinds].sort());
    expect([...FLIGHT_KINDS].sort()).toEqual([...served.flight_kinds].sort());
  });
});
