/** Files from a drop (folders walked recursively) or from file inputs, with their relative paths. */

export interface PickedFile {
  file: File;
  path: string;
}

function readAll(reader: any): Promise<any[]> {
  return new Promise((resolve, reject) => {
    const out: any[] = [];
    const next = () =>
      reader.readEntries((batch: any[]) => {
        if (!batch.length) resolve(out);
        else {
          out.push(...batch);
          next();
        }
      }, reject);
    next();
  });
}

async function walk(entry: any, prefix: string, out: PickedFile[]): Promise<void> {
  if (entry.isFile) {
    const file: File = await new Promise((res, rej) => entry.file(res, rej));
    out.push({ file, path: prefix + entry.name });
  } else if (entry.isDirectory) {
    const children = await readAll(entry.createReader());
    for (const c of children) await walk(c, `${prefix}${entry.name}/`, out);
  }
}

export async function filesFromDrop(dt: DataTransfer): Promise<PickedFile[]> {
  const out: PickedFile[] = [];
  const items = Array.from(dt.items ?? []);
  const entries = items.map((i) => (i.kind === "file" && (i as any).webkitGetAsEntry ? (i as any).webkitGetAsEntry() : null));
  if (entries.some((e) => e)) {
    for (const e of entries) if (e) await walk(e, "", out);
    return out;
  }
  for (const f of Array.from(dt.files ?? [])) out.push({ file: f, path: f.name });
  return out;
}

export function filesFromInput(input: HTMLInputElement): PickedFile[] {
  return Array.from(input.files ?? []).map((f) => ({ file: f, path: (f as any).webkitRelativePath || f.name }));
}

/** Hidden files and OS clutter that are never survey data. */
export function isClutter(path: string): boolean {
  const name = path.split("/").pop() ?? "";
  return name.startsWith(".") || name === "Thumbs.db" || name === "desktop.ini" || path.includes("__MACOSX/");
}
