import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));

export function fixture(name: string): Uint8Array {
  return new Uint8Array(readFileSync(join(here, "fixtures", name)));
}

export function fixtureText(name: string): string {
  return readFileSync(join(here, "fixtures", name), "latin1");
}

export function blobOf(bytes: Uint8Array): Blob {
  return new Blob([bytes]);
}
