/**
 * Survey data: drop the flight's folder (or pick files), see what each file is and what is missing
 * before anything is sent, upload with resumable chunks, then check on the server and start processing.
 */

import { useEffect, useMemo, useRef, useState } from "preact/hooks";
import { api, mapLimit } from "../api/client";
import type { Check, SurveyFile } from "../api/types";
import { ErrorBox, Loading, Note, ProgressBar } from "../components/ui";
import { useLoad } from "../hooks";
import { formatBytes, formatDuration } from "../lib/format";
import { scanObservationFile } from "../lib/obsScan";
import { type CheckedFile, type Problem, assignRoles, isoUtc, markFlights, preflight, spanOf, summarise } from "../lib/preflight";
import { type ObsRole, type Sniffed, type UploadKind, isObservation, sniffFile, uploadKindOf } from "../lib/sniff";
import { type PickedFile, filesFromDrop, filesFromInput, isClutter } from "../upload/collect";
import { type UploadItem, UploadQueue } from "../upload/uploader";
import { useStartRun } from "./startRun";
import type { SurveyContext } from "./surveyContext";

interface LocalFile extends CheckedFile {
  file: File;
  include: boolean;
}

/** The upload kind of a local file: a DJI flight folder's files go with kind=flight and their folder. */
function kindToSend(f: LocalFile): UploadKind | null {
  return f.flight ? "flight" : uploadKindOf(f.sniff, f.role);
}

const GROUPS: [string, string, (f: LocalFile) => boolean][] = [
  ["flights", "DJI flights (Timestamp.MRK, raw logs)", (f) => !!f.flight && f.sniff.kind !== "image"],
  ["rover", "Drone GNSS (rover)", (f) => isObservation(f.sniff.kind) && !f.flight && f.role === "rover"],
  ["base", "Base station", (f) => isObservation(f.sniff.kind) && !f.flight && f.role === "base"],
  ["obs", "GNSS observations — which receiver?", (f) => isObservation(f.sniff.kind) && !f.flight && !f.role],
  ["nav", "Navigation", (f) => f.sniff.kind === "rinex-nav" && !f.flight],
  ["images", "Photos", (f) => f.sniff.kind === "image"],
  ["points", "Ground points and measurements", (f) => ["points", "gcp-list", "events", "survey-metadata", "site-calibration"].includes(f.sniff.kind)],
  ["archive", "Archives", (f) => f.sniff.kind === "archive"],
  ["other", "Not used", (f) => ["unknown", "readme", "rinex-met"].includes(f.sniff.kind)],
];

export function UploadView({ ctx }: { ctx: SurveyContext }) {
  const surveyId = ctx.survey.id;
  const serverFiles = useLoad((signal) => api.get<SurveyFile[]>(`/surveys/${surveyId}/files`, { signal }), [surveyId]);
  const check = useLoad((signal) => api.get<Check>(`/surveys/${surveyId}/check`, { signal }), [surveyId]);
  const [local, setLocal] = useState<LocalFile[]>([]);
  const [reading, setReading] = useState<{ done: number; total: number } | null>(null);
  const [dragOver, setDragOver] = useState(false);
  const [, setTick] = useState(0);
  const [error, setError] = useState<Error | null>(null);
  const queueRef = useRef<UploadQueue | null>(null);
  if (!queueRef.current) queueRef.current = new UploadQueue(surveyId, () => setTick((t) => t + 1));
  const queue = queueRef.current;

  // Leaving the page while uploading: the browser asks first (resume is possible, but be kind).
  useEffect(() => {
    const h = (e: BeforeUnloadEvent) => {
      if (queue.running) {
        e.preventDefault();
        e.returnValue = "";
      }
    };
    window.addEventListener("beforeunload", h);
    return () => window.removeEventListener("beforeunload", h);
  }, [queue]);

  const finishedOnce = useRef(false);
  useEffect(() => {
    if (queue.finished && !queue.running && !finishedOnce.current) {
      finishedOnce.current = true;
      serverFiles.reload();
      check.reload();
    }
  });

  const addFiles = async (picked: PickedFile[]) => {
    const fresh = picked.filter((p) => !isClutter(p.path) && p.file.size > 0 && !local.some((l) => l.path === p.path && l.size === p.file.size));
    if (!fresh.length) return;
    setReading({ done: 0, total: fresh.length });
    setError(null);
    let done = 0;
    try {
      const sniffed = await mapLimit(fresh, 8, async (p) => {
        let sniff: Sniffed;
        try {
          sniff = await sniffFile(p.file, p.path);
        } catch (e) {
          sniff = { kind: "unknown", compression: "none", hatanaka: false, description: "unreadable", problem: String((e as Error).message) };
        }
        done++;
        if (done % 10 === 0 || done === fresh.length) setReading({ done, total: fresh.length });
        return { file: p.file, path: p.path, size: p.file.size, sniff, role: null, include: true } as LocalFile;
      });
      const all = [...local, ...sniffed];
      // Rover candidates: read them whole for the camera events and the true time span.
      const obs = all.filter((f) => (f.sniff.kind === "rinex-obs" || f.sniff.kind === "ubx") && f.scan === undefined);
      markFlights(all);
      await mapLimit(obs, 2, async (f) => {
        try {
          f.scan = await scanObservationFile(f.file, f.sniff);
        } catch {
          f.scan = null;
        }
      });
      assignRoles(all);
      for (const f of all) f.include = kindToSend(f) !== null || isObservation(f.sniff.kind);
      setLocal(all);
    } catch (e) {
      setError(e as Error);
    } finally {
      setReading(null);
    }
  };

  const problems: Problem[] = useMemo(() => (local.length ? preflight(local.filter((f) => f.include || f.sniff.kind === "unknown")) : []), [local]);
  const summary = useMemo(() => (local.length ? summarise(local.filter((f) => f.include)) : ""), [local]);
  const errors = problems.filter((p) => p.severity === "error");
  const toSend = local.filter((f) => f.include && kindToSend(f));
  const sendBytes = toSend.reduce((a, f) => a + f.size, 0);
  const unassigned = local.some((f) => f.include && isObservation(f.sniff.kind) && !f.flight && !f.role);

  const setRole = (f: LocalFile, role: ObsRole) => {
    f.role = role;
    setLocal([...local]);
  };

  const startUpload = () => {
    queue.add(toSend.map((f) => ({ file: f.file, path: f.path, kind: kindToSend(f)!, role: f.flight ? null : f.role, folder: f.flight ?? undefined })));
    finishedOnce.current = false;
    queue.start();
  };

  const onDrop = async (e: DragEvent) => {
    e.preventDefault();
    setDragOver(false);
    if (e.dataTransfer) await addFiles(await filesFromDrop(e.dataTransfer));
  };

  const serverHasData = (serverFiles.data?.length ?? 0) > 0;

  return (
    <div class="upload">
      {!ctx.canEdit ? <Note>You can look at this survey's data; uploading needs the editor role on the site.</Note> : (
        <>
          <h2 class="sr-only">Add data</h2>
          <div
            class={dragOver ? "dropzone over" : "dropzone"}
            onDragOver={(e) => { e.preventDefault(); setDragOver(true); }}
            onDragLeave={() => setDragOver(false)}
            onDrop={onDrop}
          >
            <p class="drop-title">Drop the flight's folder here</p>
            <p class="muted">Drone GNSS log, base station observations, navigation file, photos, ground points — in any folder layout; files are recognised by their content.</p>
            <div class="drop-buttons">
              <label class="button secondary">
                Choose a folder…
                <input type="file" class="visually-hidden-input" {...({ webkitdirectory: "", directory: "" } as any)} multiple onChange={(e) => { addFiles(filesFromInput(e.target as HTMLInputElement)); (e.target as HTMLInputElement).value = ""; }} />
              </label>
              <label class="button secondary">
                Choose files…
                <input type="file" class="visually-hidden-input" multiple data-testid="file-input" onChange={(e) => { addFiles(filesFromInput(e.target as HTMLInputElement)); (e.target as HTMLInputElement).value = ""; }} />
              </label>
            </div>
            {reading ? <div aria-live="polite"><ProgressBar value={reading.done} max={reading.total} label="Reading files" text={`${reading.done} of ${reading.total} files read`} /> <span class="small muted">Reading {reading.done} / {reading.total} files…</span></div> : null}
          </div>
          <ErrorBox error={error} />
        </>
      )}

      {local.length ? (
        <section aria-labelledby="found-title">
          <h2 id="found-title">What was found</h2>
          <FileGroups files={local} onRole={setRole} onToggle={(f) => { f.include = !f.include; setLocal([...local]); }} locked={queue.running || queue.items.length > 0} />
          <h3>Before uploading</h3>
          {summary ? <p class="check-summary" data-testid="local-summary">Found: {summary}</p> : null}
          <ProblemList problems={problems} empty="Everything needed for processing is there." />
          {queue.items.length === 0 ? (
            <div class="actions">
              <button type="button" class="primary" onClick={startUpload} disabled={!toSend.length || unassigned}>
                Upload {toSend.length} file{toSend.length === 1 ? "" : "s"} ({formatBytes(sendBytes)})
              </button>
              {errors.length ? <span class="small warn-text">{errors.length} problem{errors.length > 1 ? "s" : ""} above: you can upload now and add the missing files later.</span> : null}
              <button type="button" class="ghost" onClick={() => setLocal([])}>Clear</button>
            </div>
          ) : null}
        </section>
      ) : null}

      {queue.items.length ? <UploadProgress queue={queue} /> : null}

      <section aria-labelledby="server-title">
        <h2 id="server-title">On the server</h2>
        <ErrorBox error={serverFiles.error} />
        {serverFiles.loading && !serverFiles.data ? <Loading what="the survey's files" /> : null}
        {serverFiles.data && !serverFiles.data.length ? <p class="muted">No file uploaded yet.</p> : null}
        {serverFiles.data && serverFiles.data.length ? <ServerFiles files={serverFiles.data} surveyId={surveyId} canEdit={ctx.canEdit} onChange={() => { serverFiles.reload(); check.reload(); }} /> : null}
        {serverHasData && check.data ? (
          <>
            <h3>Server check</h3>
            {check.data.summary ? <p class="check-summary" data-testid="server-summary">Found: {check.data.summary}</p> : null}
            <ProblemList problems={check.data.problems} empty="Ready to process." />
          </>
        ) : null}
        {serverHasData && ctx.canEdit ? <StartProcessing ctx={ctx} ready={!!check.data?.ok} busyUpload={queue.running} /> : null}
      </section>
    </div>
  );
}

function FileGroups({ files, onRole, onToggle, locked }: { files: LocalFile[]; onRole: (f: LocalFile, r: ObsRole) => void; onToggle: (f: LocalFile) => void; locked: boolean }) {
  return (
    <div class="file-groups">
      {GROUPS.map(([id, title, test]) => {
        const fs = files.filter(test);
        if (!fs.length) return null;
        if (id === "images") return <ImagesGroup key={id} files={fs} />;
        return (
          <div key={id} class={`file-group group-${id}`}>
            <h3>{title} <span class="muted small">({fs.length})</span></h3>
            <ul class="file-list">
              {fs.map((f) => (
                <li key={f.path}>
                  <span class="file-path" title={f.path}>{f.path}</span>
                  <span class="file-desc">{f.sniff.description}{detailOf(f)}</span>
                  <span class="file-size">{formatBytes(f.size)}</span>
                  {isObservation(f.sniff.kind) && !f.flight ? (
                    <span class="role-pick" role="radiogroup" aria-label={`Receiver of ${f.path}`}>
                      {(["rover", "base"] as const).map((r) => (
                        <label key={r} class="radio">
                          <input type="radio" name={`role-${f.path}`} checked={f.role === r} disabled={locked} onChange={() => onRole(f, r)} /> {r === "rover" ? "drone" : "base"}
                        </label>
                      ))}
                    </span>
                  ) : id === "other" ? null : (
                    <label class="radio">
                      <input type="checkbox" checked={f.include} disabled={locked} onChange={() => onToggle(f)} /> upload
                    </label>
                  )}
                  {f.sniff.problem ? <span class="file-problem">{f.sniff.problem}</span> : null}
                </li>
              ))}
            </ul>
          </div>
        );
      })}
    </div>
  );
}

function detailOf(f: LocalFile): string {
  const parts: string[] = [];
  const span = spanOf(f);
  if (span) parts.push(`${isoUtc(span.firstMs).slice(0, 16)} – ${isoUtc(span.lastMs).slice(11, 16)} (${formatDuration((span.lastMs - span.firstMs) / 1000)})`);
  if (f.scan?.events) parts.push(`${f.scan.events} camera events`);
  if (f.sniff.rinex?.markerName) parts.push(`marker ${f.sniff.rinex.markerName}`);
  if (f.flight !== undefined && f.flight !== null) parts.push(`flight ${f.flight || "(top folder)"}`);
  return parts.length ? ` · ${parts.join(" · ")}` : "";
}

function ImagesGroup({ files }: { files: LocalFile[] }) {
  const [open, setOpen] = useState(false);
  const bytes = files.reduce((a, f) => a + f.size, 0);
  const jpeg = files.filter((f) => f.sniff.image?.format === "jpeg").length;
  const times = files.map((f) => f.sniff.image?.capture?.ms).filter((x): x is number => typeof x === "number");
  return (
    <div class="file-group group-images">
      <h3>Photos <span class="muted small">({files.length})</span></h3>
      <p>
        {files.length} photos ({jpeg} JPEG, {files.length - jpeg} TIFF), {formatBytes(bytes)}
        {times.length ? ` · taken ${isoUtc(Math.min(...times)).slice(0, 16)} – ${isoUtc(Math.max(...times)).slice(11, 16)}` : ""}{" "}
        <button type="button" class="link small" aria-expanded={open} onClick={() => setOpen(!open)}>{open ? "Hide list" : "Show list"}</button>
      </p>
      {open ? (
        <ul class="file-list compact">
          {files.slice(0, 1000).map((f) => (
            <li key={f.path}><span class="file-path">{f.path}</span><span class="file-size">{formatBytes(f.size)}</span></li>
          ))}
        </ul>
      ) : null}
    </div>
  );
}

const SEVERITY_WORD = { error: "Problem", warning: "Warning", info: "Note" } as const;

export function ProblemList({ problems, empty }: { problems: { severity: "error" | "warning" | "info"; code: string; message: string; files: string[] }[]; empty: string }) {
  if (!problems.length) return <Note kind="ok">{empty}</Note>;
  return (
    <ul class="problems" aria-live="polite">
      {problems.map((p, i) => (
        <li key={`${p.code}${i}`} class={`problem problem-${p.severity}`} data-code={p.code}>
          <strong>{SEVERITY_WORD[p.severity]}:</strong> {p.message}
          {p.files.length ? <div class="small muted">{p.files.slice(0, 6).join(", ")}{p.files.length > 6 ? ` and ${p.files.length - 6} more` : ""}</div> : null}
        </li>
      ))}
    </ul>
  );
}

const ITEM_WORD: Record<string, string> = { waiting: "waiting", hashing: "checksum", uploading: "uploading", verifying: "verifying", done: "done", error: "failed", paused: "paused" };

function UploadProgress({ queue }: { queue: UploadQueue }) {
  const total = queue.totalBytes;
  const sent = queue.sentBytes;
  const rate = queue.rate;
  const left = rate ? (total - sent) / rate : null;
  const failed = queue.items.filter((i) => i.state === "error");
  const active = queue.items.filter((i) => i.state !== "done" || queue.items.length <= 30);
  const shown = [...active.filter((i) => i.state !== "waiting" && i.state !== "done"), ...active.filter((i) => i.state === "waiting" || i.state === "done")].slice(0, 60);
  const doneCount = queue.items.filter((i) => i.state === "done").length;
  return (
    <section aria-labelledby="upload-title" class="card">
      <h2 id="upload-title">Upload</h2>
      <ProgressBar value={sent} max={total} label="Overall upload" text={`${formatBytes(sent)} of ${formatBytes(total)}`} />
      <p class="small" aria-live="polite">
        {doneCount} of {queue.items.length} files · {formatBytes(sent)} of {formatBytes(total)}
        {rate ? ` · ${formatBytes(rate)}/s · about ${formatDuration(left)} left` : ""}
        {queue.finished ? " · all files uploaded" : ""}
      </p>
      <div class="actions">
        {queue.running ? <button type="button" class="secondary" onClick={() => queue.pause()}>Pause</button> : null}
        {!queue.running && !queue.finished ? <button type="button" class="primary" onClick={() => queue.start()}>{failed.length ? "Retry" : "Resume"}</button> : null}
      </div>
      <ul class="upload-items">
        {shown.map((i: UploadItem) => (
          <li key={i.key} class={`up-${i.state}`}>
            <span class="file-path" title={i.path}>{i.path}</span>
            <span class="up-state">{ITEM_WORD[i.state]}{i.attempts ? ` (try ${i.attempts + 1})` : ""}</span>
            <ProgressBar value={i.state === "hashing" ? i.hashed : i.state === "done" ? i.size : i.sent} max={i.size} label={`${i.path} ${ITEM_WORD[i.state]}`} />
            {i.error ? <span class="file-problem">{i.error}</span> : null}
          </li>
        ))}
      </ul>
      {queue.items.length > shown.length ? <p class="small muted">{queue.items.length - shown.length} more files not listed.</p> : null}
    </section>
  );
}

function ServerFiles({ files, surveyId, canEdit, onChange }: { files: SurveyFile[]; surveyId: string; canEdit: boolean; onChange: () => void }) {
  const [error, setError] = useState<Error | null>(null);
  const byFolder = new Map<string, SurveyFile[]>();
  for (const f of files) {
    const folder = f.path.includes("/") ? f.path.split("/")[0] : "(survey folder)";
    byFolder.set(folder, [...(byFolder.get(folder) ?? []), f]);
  }
  const act = async (f: () => Promise<unknown>) => {
    setError(null);
    try {
      await f();
      onChange();
    } catch (e) {
      setError(e as Error);
    }
  };
  return (
    <>
      <ErrorBox error={error} />
      <div class="table-wrap">
        <table class="data compact">
          <thead><tr><th scope="col">File</th><th scope="col">Kind</th><th scope="col" class="num">Size</th><th scope="col"><span class="sr-only">Actions</span></th></tr></thead>
          <tbody>
            {[...byFolder.entries()].map(([folder, fs]) =>
              folder === "images" && fs.length > 5 ? (
                <tr key={folder}><td>images/ ({fs.length} photos)</td><td>image</td><td class="num">{formatBytes(fs.reduce((a, f) => a + f.size, 0))}</td><td /></tr>
              ) : (
                fs.map((f) => (
                  <tr key={f.id}>
                    <td>{f.path}</td>
                    <td>{f.kind}{f.role ? ` (${f.role})` : ""}</td>
                    <td class="num">{formatBytes(f.size)}</td>
                    <td class="row-actions">
                      {canEdit && ["rinex-obs", "ubx", "rtcm3"].includes(f.kind) && !f.path.startsWith("flights/") ? (
                        <button type="button" class="link small" onClick={() => act(() => api.patch(`/surveys/${surveyId}/files/${f.id}`, { role: f.role === "rover" ? "base" : "rover" }))}>
                          make {f.role === "rover" ? "base" : "rover"}
                        </button>
                      ) : null}
                      {canEdit ? <button type="button" class="link small danger" aria-label={`Remove ${f.path}`} onClick={() => confirm(`Remove ${f.path} from the survey?`) && act(() => api.del(`/surveys/${surveyId}/files/${f.id}`))}>remove</button> : null}
                    </td>
                  </tr>
                ))
              ),
            )}
          </tbody>
        </table>
      </div>
    </>
  );
}

function StartProcessing({ ctx, ready, busyUpload }: { ctx: SurveyContext; ready: boolean; busyUpload: boolean }) {
  const { start, busy, error } = useStartRun(ctx);
  return (
    <div class="actions">
      <button type="button" class="primary" onClick={start} disabled={busy || busyUpload}>{busy ? "Starting…" : "Start processing"}</button>
      {!ready ? <span class="small warn-text">The server check reports problems: processing may fail.</span> : null}
      <ErrorBox error={error} />
    </div>
  );
}
