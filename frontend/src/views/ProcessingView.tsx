/**
 * Processing: the steps of a run with live progress (server-sent events), time estimates and logs;
 * cancel; re-run from a step with changed settings.
 */

import { useEffect, useMemo, useRef, useState } from "preact/hooks";
import { api, apiUrl, getAllPages } from "../api/client";
import type { LogLine, Run, RunDetail, Step } from "../api/types";
import { CalibrationTable } from "../components/CalibrationTable";
import { ErrorBox, Loading, Note, ProgressBar, StatePill } from "../components/ui";
import { useLoad } from "../hooks";
import { calibrationOf } from "../lib/calibration";
import { EtaEstimator } from "../lib/eta";
import { formatDateTime, formatDuration } from "../lib/format";
import { loadSteps, parseSetting, settingFields, type SettingField } from "../lib/steps";
import { runHref, showRun, useStartRun } from "./startRun";
import type { SurveyContext } from "./surveyContext";

const STEP_TITLE: Record<string, string> = {
  gnss: "GNSS trajectory (PPK)",
  georef: "Georeferencing (photos, lever arm, check points)",
  dense: "Surface model and orthophoto",
  volumes: "Stockpile volumes",
  report: "Accuracy report (PDF)",
};
const TERMINAL = ["succeeded", "failed", "cancelled"];

function stepSeconds(s: Step): number | null {
  if (!s.started_at) return null;
  const end = s.finished_at ? Date.parse(s.finished_at) : Date.now();
  return Math.max(0, (end - Date.parse(s.started_at)) / 1000);
}

export function ProcessingView({ ctx, runId }: { ctx: SurveyContext; runId: string | null }) {
  const runs = ctx.runs;
  const selected = (runId ? runs.find((r) => r.id === runId) : null) ?? runs[0] ?? null;
  if (!runs.length) {
    return (
      <div>
        <p class="empty">This survey has not been processed yet.</p>
        {ctx.canEdit ? <StartRun ctx={ctx} /> : null}
      </div>
    );
  }
  return (
    <div class="processing">
      <aside class="run-list" aria-label="Runs">
        <h2 class="h3">Runs</h2>
        <ul>
          {runs.map((r) => (
            <li key={r.id}>
              <a href={runHref(ctx, r.id)} aria-current={r.id === selected?.id ? "true" : undefined} class={r.id === selected?.id ? "active" : ""}>
                <span>Run {r.number}</span> <StatePill state={r.state} />
                <span class="small muted block">{r.trigger}{r.from_step ? ` from ${r.from_step}` : ""} · {formatDateTime(r.created_at)}</span>
              </a>
            </li>
          ))}
        </ul>
        {ctx.canEdit ? <StartRun ctx={ctx} compact /> : null}
      </aside>
      {selected ? <RunPanel key={selected.id} ctx={ctx} run={selected} /> : null}
    </div>
  );
}

function StartRun({ ctx, compact }: { ctx: SurveyContext; compact?: boolean }) {
  const { start, busy, error } = useStartRun(ctx);
  return (
    <div class={compact ? "start-run compact" : "start-run"}>
      <button type="button" class={compact ? "secondary" : "primary"} onClick={start} disabled={busy}>{compact ? "New run" : "Start processing"}</button>
      <ErrorBox error={error} />
    </div>
  );
}

function RunPanel({ ctx, run }: { ctx: SurveyContext; run: Run }) {
  const [detail, setDetail] = useState<RunDetail | null>(null);
  const [logs, setLogs] = useState<LogLine[]>([]);
  const [error, setError] = useState<Error | null>(null);
  const [live, setLive] = useState(false);
  const estimators = useRef(new Map<string, EtaEstimator>());
  const [, force] = useState(0);

  // Step durations of the previous successful run: the prior of the time estimates.
  const prior = useLoad(async (signal) => {
    const prev = run.previous_run_id ?? run.parent_run_id;
    if (!prev) return {} as Record<string, number>;
    const d = await api.maybe<RunDetail>(`/runs/${prev}`, { signal });
    const out: Record<string, number> = {};
    for (const s of d?.step_details ?? []) {
      const t = stepSeconds(s);
      if (s.state === "succeeded" && t !== null && !s.reused_from_step_id) out[s.name] = t;
    }
    return out;
  }, [run.id]);

  useEffect(() => {
    let es: EventSource | null = null;
    let stopped = false;
    const ingest = (d: RunDetail) => {
      const now = performance.now();
      for (const s of d.step_details) {
        if (s.state !== "running" || !s.progress_total) continue;
        let e = estimators.current.get(s.name);
        if (!e) estimators.current.set(s.name, (e = new EtaEstimator()));
        e.add(now, s.progress_done);
      }
      setDetail(d);
    };
    (async () => {
      try {
        const [d, l] = await Promise.all([api.get<RunDetail>(`/runs/${run.id}`), getAllPages<LogLine>(`/runs/${run.id}/logs`, { max: 5000 })]);
        if (stopped) return;
        ingest(d);
        setLogs(l);
        if (TERMINAL.includes(d.state)) return;
        es = new EventSource(apiUrl(`/runs/${run.id}/events`), { withCredentials: true });
        setLive(true);
        es.addEventListener("state", (ev) => ingest(JSON.parse((ev as MessageEvent).data)));
        es.addEventListener("log", (ev) => {
          const line = JSON.parse((ev as MessageEvent).data) as LogLine;
          setLogs((prev) => (prev.some((x) => x.id === line.id) ? prev : [...prev, line]));
        });
        es.addEventListener("end", () => {
          es?.close();
          setLive(false);
          ctx.reloadRuns();
        });
        es.onerror = () => {
          // The browser reconnects by itself (Last-Event-ID resumes the log); show it meanwhile.
          if (es?.readyState === EventSource.CLOSED) setLive(false);
        };
      } catch (e) {
        if (!stopped) setError(e as Error);
      }
    })();
    const tick = setInterval(() => force((x) => x + 1), 1000); // elapsed times move on
    return () => {
      stopped = true;
      es?.close();
      clearInterval(tick);
    };
  }, [run.id]);

  // Keep the run list (and the result tabs) in step with what the live view sees.
  const seenState = useRef(run.state);
  useEffect(() => {
    if (detail && detail.state !== seenState.current) {
      seenState.current = detail.state;
      ctx.reloadRuns();
    }
  }, [detail?.state]);

  if (error) return <ErrorBox error={error} title="This run could not be loaded" />;
  if (!detail) return <Loading what="the run" />;

  const running = !TERMINAL.includes(detail.state);
  const remaining = detail.step_details.reduce((acc, s) => {
    if (s.state === "pending" || s.state === "queued") return acc + (prior.data?.[s.name] ?? 0);
    if (s.state === "running") return acc + (etaOf(s) ?? 0);
    return acc;
  }, 0);
  function etaOf(s: Step): number | null {
    const e = estimators.current.get(s.name);
    const elapsed = stepSeconds(s);
    return e && s.progress_total ? e.secondsLeft(s.progress_total, prior.data?.[s.name], elapsed) : prior.data?.[s.name] != null && elapsed != null ? Math.max(0, prior.data[s.name] - elapsed) : null;
  }

  return (
    <div class="run-panel">
      <div class="page-head">
        <h2>Run {detail.number} <StatePill state={detail.state} /></h2>
        {live ? <span class="live" aria-label="live updates">● live</span> : null}
        <span class="spacer" />
        {running && ctx.canEdit ? <CancelButton run={detail} onDone={setDetail} /> : null}
      </div>
      <p class="small muted" aria-live="polite">
        {detail.trigger}{detail.from_step ? `, recomputing from ${detail.from_step}` : ""} · created {formatDateTime(detail.created_at)}
        {detail.finished_at ? ` · finished ${formatDateTime(detail.finished_at)}` : ""}
        {running && remaining > 0 ? ` · about ${formatDuration(remaining)} left` : ""}
        {detail.cancel_requested && running ? " · cancelling…" : ""}
      </p>
      {detail.error ? <ErrorBox error={detail.error} title="The run stopped" /> : null}
      <ol class="steps">
        {detail.step_details.map((s) => {
          const t = stepSeconds(s);
          const eta = s.state === "running" ? etaOf(s) : null;
          return (
            <li key={s.name} class={`step step-${s.state}`} data-step={s.name}>
              <div class="step-head">
                <span class="step-name">{STEP_TITLE[s.name] ?? s.name}</span>
                <StatePill state={s.state} />
                {s.reused_from_step_id ? <span class="small muted">reused from an earlier run (same inputs)</span> : null}
                <span class="spacer" />
                <span class="small muted">
                  {t !== null ? formatDuration(t) : s.state === "pending" && prior.data?.[s.name] ? `usually ${formatDuration(prior.data[s.name])}` : ""}
                  {eta !== null ? ` · ${formatDuration(eta)} left` : ""}
                </span>
              </div>
              {s.state === "running" ? (
                <>
                  <ProgressBar value={s.progress_total ? s.progress_done : 0} max={s.progress_total || 1} label={`${s.name} progress`} text={s.progress_total ? `${s.progress_done} of ${s.progress_total}` : "started"} />
                  <div class="small muted">{s.progress_stage}{s.progress_total ? ` · ${s.progress_done} / ${s.progress_total}` : ""}</div>
                </>
              ) : null}
              {s.error ? <div class="step-error">{s.error}</div> : null}
              {(s.state === "succeeded" || (s.state === "skipped" && !s.reused_from_step_id)) && s.summary ? <StepSummary step={s} /> : null}
            </li>
          );
        })}
      </ol>
      {!running && ctx.canEdit ? <Rerun ctx={ctx} run={detail} /> : null}
      <LogView logs={logs} steps={detail.steps} />
    </div>
  );
}

function StepSummary({ step }: { step: Step }) {
  const s = step.summary ?? {};
  const bits: string[] = [];
  const pick = (o: any, ...keys: string[]) => keys.map((k) => o?.[k]).find((v) => v !== undefined && v !== null);
  if (s.skipped === true) {
    // a step with nothing to do, e.g. the GNSS step of a survey of photos alone: its reason
    return <div class="small">{`skipped: ${s.reason ?? "nothing to do"}`}</div>;
  }
  if (step.name === "gnss") {
    const fix = pick(s, "fix_rate", "fixed_fraction", "fix_ratio") ?? pick(s.quality, "fix_rate", "fixed_fraction");
    if (typeof fix === "number") bits.push(`${Math.round((fix <= 1 ? fix * 100 : fix))} % fixed`);
    const ep = pick(s, "epochs", "n_epochs");
    if (typeof ep === "number") bits.push(`${ep} epochs`);
    const ev = s.events?.count ?? s.events?.n;
    if (typeof ev === "number") bits.push(`${ev} camera events`);
  } else if (step.name === "georef") {
    const im = s.images;
    if (im?.registered !== undefined) bits.push(`${im.registered} of ${im.total} photos oriented`);
    const rms = s.check_points?.statistics?.["3d"]?.rmse_m;
    if (typeof rms === "number") bits.push(`check RMSE ${(rms * 100).toFixed(1)} cm`);
    if (Array.isArray(s.cameras) && s.cameras.length > 1) bits.push(`${s.cameras.length} cameras`);
    // what the absolute position rests on, the block's bending, and what was left out (named)
    const lines: string[] = [];
    if (typeof s.absolute_accuracy?.text === "string") lines.push(s.absolute_accuracy.text);
    if (typeof s.doming?.text === "string") lines.push(s.doming.text);
    const warnings: string[] = Array.isArray(s.warnings) ? s.warnings.filter((w: unknown) => typeof w === "string") : [];
    const notable = warnings.filter((w) => w.includes(": left out") || w.startsWith("doming")
      || w.startsWith("EXIF heights inconsistent"));
    return (
      <div class="small step-georef-summary">
        {bits.length ? <div>{bits.join(" · ")}</div> : null}
        {lines.map((l) => <div key={l}>{l}</div>)}
        {notable.map((w) => <div key={w} class="warning-text">{w}</div>)}
      </div>
    );
  }
  if (step.name === "datum") {
    // heights in the site's datum and, where the run has one, the site calibration with its residuals
    if (typeof s.datum === "string") bits.push(`heights: ${s.datum}`);
    const cal = calibrationOf(s);
    return (
      <div class="small">
        {bits.length ? <div>{bits.join(" · ")}</div> : null}
        {cal ? <CalibrationTable c={cal} /> : null}
      </div>
    );
  }
  return bits.length ? <div class="small">{bits.join(" · ")}</div> : null;
}

function CancelButton({ run, onDone }: { run: RunDetail; onDone: (d: RunDetail) => void }) {
  const [error, setError] = useState<Error | null>(null);
  const cancel = async () => {
    if (!confirm(`Cancel run ${run.number}? Finished steps are kept and reused by the next run.`)) return;
    try {
      onDone(await api.post<RunDetail>(`/runs/${run.id}/cancel`, {}));
    } catch (e) {
      setError(e as Error);
    }
  };
  return (
    <>
      <button type="button" class="danger" onClick={cancel} disabled={run.cancel_requested}>Cancel run</button>
      <ErrorBox error={error} />
    </>
  );
}

/** One option of a step's spec as a form field (choices and yes/no as selects, the rest as text parsed by kind). */
function SettingInput({ f, value, onChange }: { f: SettingField; value: unknown; onChange: (v: unknown) => void }) {
  const id = `set-${f.section}-${f.key}`;
  const [bad, setBad] = useState<string | null>(null);
  const dflt = f.default === undefined || f.default === null ? "" : ` (default ${JSON.stringify(f.default)})`;
  return (
    <div class="field">
      <label for={id}>{f.label} <span class="muted small">({f.section}.{f.key}{f.unit ? `, ${f.unit}` : ""})</span></label>
      {f.kind === "choice" || f.kind === "bool" ? (
        <select id={id} value={value === undefined ? "" : String(value)}
          onChange={(e) => { const v = (e.target as HTMLSelectElement).value; onChange(v === "" ? undefined : f.kind === "bool" ? v === "true" : v); }}>
          <option value="">default{dflt}</option>
          {f.kind === "bool" ? [<option key="t" value="true">yes</option>, <option key="f" value="false">no</option>]
            : f.options!.map((o) => <option key={o} value={o}>{o}</option>)}
        </select>
      ) : (
        <input id={id} type="text" inputMode={f.kind === "number" || f.kind === "integer" ? "decimal" : undefined}
          placeholder={`default${dflt}`} value={value === undefined ? "" : typeof value === "string" ? value : JSON.stringify(value)}
          aria-invalid={bad ? true : undefined}
          onChange={(e) => {
            try {
              onChange(parseSetting(f, (e.target as HTMLInputElement).value));
              setBad(null);
            } catch (err) {
              setBad((err as Error).message);
            }
          }} />
      )}
      {bad ? <small class="hint error">{bad}</small> : null}
    </div>
  );
}

function Rerun({ ctx, run }: { ctx: SurveyContext; run: RunDetail }) {
  const [open, setOpen] = useState(false);
  const firstFailed = run.step_details.find((s) => s.state === "failed" || s.state === "cancelled")?.name;
  const [fromStep, setFromStep] = useState(firstFailed ?? run.steps[0] ?? "gnss");
  const [settings, setSettings] = useState<Record<string, Record<string, unknown>>>(() => JSON.parse(JSON.stringify(run.settings ?? {})));
  const [json, setJson] = useState<string | null>(null);
  const [error, setError] = useState<Error | null>(null);
  const [busy, setBusy] = useState(false);
  const text = useMemo(() => JSON.stringify(settings, null, 2), [settings]);

  const steps = useLoad((signal) => loadSteps(signal), []);
  const fields = useMemo(() => (steps.data ? settingFields(steps.data) : []), [steps.data]);
  const setValue = (k: { section: string; key: string }, v: unknown) => {
    const next = { ...settings, [k.section]: { ...(settings[k.section] ?? {}) } };
    if (v === "" || v === undefined) delete next[k.section][k.key];
    else next[k.section][k.key] = v;
    if (!Object.keys(next[k.section]).length) delete next[k.section];
    setSettings(next);
    setJson(null);
  };

  const submit = async (e: Event) => {
    e.preventDefault();
    setError(null);
    let body = settings;
    if (json !== null) {
      try {
        body = JSON.parse(json);
      } catch (err) {
        setError(new Error(`Settings are not valid JSON: ${(err as Error).message}`));
        return;
      }
    }
    setBusy(true);
    try {
      const r = await api.post<RunDetail>(`/runs/${run.id}/rerun`, { from_step: fromStep, settings: body });
      showRun(ctx, r.id);
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };

  if (!open) {
    return (
      <div class="actions">
        <button type="button" class="secondary" onClick={() => setOpen(true)} aria-expanded={false}>Re-run from a step…</button>
      </div>
    );
  }
  return (
    <form class="card rerun" onSubmit={submit} aria-label="Re-run from a step">
      <h3>Re-run</h3>
      <div class="form-grid">
        <div class="field">
          <label for="from-step">From step</label>
          <select id="from-step" value={fromStep} onChange={(e) => setFromStep((e.target as HTMLSelectElement).value)}>
            {(steps.data ?? []).map((sp) => <option key={sp.name} value={sp.name}>{STEP_TITLE[sp.name] ?? sp.title}</option>)}
          </select>
          <small class="hint">Earlier steps with unchanged inputs and settings are reused.</small>
        </div>
        {fields.filter((f) => !f.advanced).map((f) => (
          <SettingInput key={`${f.section}-${f.key}`} f={f} value={settings[f.section]?.[f.key]} onChange={(v) => setValue(f, v)} />
        ))}
      </div>
      {steps.error ? <ErrorBox error={steps.error} /> : null}
      <details>
        <summary>Advanced settings</summary>
        <div class="form-grid">
          {fields.filter((f) => f.advanced).map((f) => (
            <SettingInput key={`${f.section}-${f.key}`} f={f} value={settings[f.section]?.[f.key]} onChange={(v) => setValue(f, v)} />
          ))}
        </div>
      </details>
      <details>
        <summary>All settings (JSON)</summary>
        <label for="settings-json" class="sr-only">Settings as JSON</label>
        <textarea id="settings-json" rows={8} spellcheck={false} value={json ?? text} onInput={(e) => setJson((e.target as HTMLTextAreaElement).value)} />
      </details>
      <ErrorBox error={error} />
      <div class="actions">
        <button type="submit" class="primary" disabled={busy}>{busy ? "Starting…" : `Re-run from ${fromStep}`}</button>
        <button type="button" class="ghost" onClick={() => setOpen(false)}>Close</button>
      </div>
    </form>
  );
}

function LogView({ logs, steps }: { logs: LogLine[]; steps: string[] }) {
  const [step, setStep] = useState("");
  const [follow, setFollow] = useState(true);
  const [level, setLevel] = useState("");
  const box = useRef<HTMLDivElement>(null);
  const shown = logs.filter((l) => (!step || l.step_name === step) && (!level || l.level === level || (level === "warning" && l.level === "error")));
  useEffect(() => {
    if (follow && box.current) box.current.scrollTop = box.current.scrollHeight;
  }, [shown.length, follow]);
  return (
    <section class="logs" aria-labelledby="logs-title">
      <div class="page-head">
        <h3 id="logs-title">Log</h3>
        <label class="small">Step <select value={step} onChange={(e) => setStep((e.target as HTMLSelectElement).value)}>
          <option value="">all</option>
          {steps.map((s) => <option key={s} value={s}>{s}</option>)}
        </select></label>
        <label class="small">Show <select value={level} onChange={(e) => setLevel((e.target as HTMLSelectElement).value)}>
          <option value="">everything</option><option value="warning">warnings and errors</option><option value="error">errors</option>
        </select></label>
        <label class="small"><input type="checkbox" checked={follow} onChange={() => setFollow(!follow)} /> follow</label>
      </div>
      {shown.length ? (
        <div class="log-box" ref={box} tabIndex={0} role="log" aria-label="Processing log">
          {shown.map((l) => (
            <div key={l.id} class={`log-line log-${l.level}`}>
              <time>{l.created_at.slice(11, 19)}</time> {l.step_name ? <span class="log-step">{l.step_name}</span> : null} {l.message}
            </div>
          ))}
        </div>
      ) : (
        <Note>No log line{step ? ` for ${step}` : ""} yet.</Note>
      )}
    </section>
  );
}
