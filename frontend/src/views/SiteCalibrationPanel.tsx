/** The site's calibration (localisation): shown with its parameters and residuals per control point
 * (GET /sites/{id}/calibration); an admin sets it from a calibration JSON or a CSV of control pairs (PUT, with
 * If-Match) or removes it. The datum step of every run of the site applies it unless the survey gives its own. */

import { useState } from "preact/hooks";
import { api, ApiError } from "../api/client";
import { CalibrationTable } from "../components/CalibrationTable";
import { ErrorBox, Loading, Note } from "../components/ui";
import { useLoad } from "../hooks";
import { siteCalibrationBody, type SiteCalibrationOut } from "../lib/calibration";
import { formatDateTime } from "../lib/format";

async function loadCalibration(siteId: string, signal: AbortSignal): Promise<{ cal: SiteCalibrationOut | null; etag: string | null }> {
  try {
    const r = await api.getWithEtag<SiteCalibrationOut>(`/sites/${siteId}/calibration`, { signal });
    return { cal: r.data, etag: r.etag };
  } catch (e) {
    if (e instanceof ApiError && e.status === 404) return { cal: null, etag: null };
    throw e;
  }
}

export function SiteCalibrationPanel({ siteId, canAdmin }: { siteId: string; canAdmin: boolean }) {
  const state = useLoad((signal) => loadCalibration(siteId, signal), [siteId]);
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);
  const [done, setDone] = useState<string | null>(null);
  if (state.error) return <ErrorBox error={state.error} title="The site calibration could not be read" />;
  if (!state.data) return <Loading what="the site calibration" />;
  const { cal, etag } = state.data;
  const ifMatch = etag ? { "If-Match": etag } : undefined;

  const act = async (f: () => Promise<unknown>, message: string) => {
    setBusy(true);
    setError(null);
    setDone(null);
    try {
      await f();
      setDone(message);
      state.reload();
    } catch (e) {
      setError(e as Error);
      if (e instanceof ApiError && e.status === 412) state.reload();
    } finally {
      setBusy(false);
    }
  };
  const pick = async (file: File) => {
    let body;
    try {
      body = siteCalibrationBody(file.name, await file.text());
    } catch (e) {
      setError(new Error(`${file.name}: ${(e as Error).message}`));
      return;
    }
    await act(() => api.put(`/sites/${siteId}/calibration`, { json: body, headers: ifMatch }),
      `${file.name} checked and stored: the next runs of surveys without a calibration of their own apply it.`);
  };

  return (
    <div class="site-calibration-panel" data-testid="site-calibration-panel">
      {cal ? (
        <>
          <p class="small muted">
            Applied by the datum step of every run of this site unless the survey (its calibration file or settings) gives its own.
            Version {cal.version}{cal.source_name ? `, from ${cal.source_name}` : ""}, set {formatDateTime(cal.updated_at)}; {cal.crs}, heights {cal.height_datum}.
          </p>
          <CalibrationTable c={{ ...cal.summary, source: undefined }} />
        </>
      ) : (
        <p class="muted">No site calibration{canAdmin ? ": set one from a calibration JSON (georef datum calibrate) or a CSV of control pairs, and every survey's run applies it." : "."}</p>
      )}
      {canAdmin ? (
        <div class="actions">
          <label class={`button ${cal ? "secondary" : "primary"} small`}>
            {busy ? "Checking…" : cal ? "Replace the calibration…" : "Set the calibration…"}
            <input type="file" accept=".json,.csv,.txt,application/json,text/csv" class="visually-hidden-input" disabled={busy}
              aria-label="Site calibration (calibration JSON or CSV of control pairs)"
              onChange={(e) => { const f = (e.target as HTMLInputElement).files?.[0]; if (f) void pick(f); (e.target as HTMLInputElement).value = ""; }} />
          </label>
          {cal ? <button type="button" class="secondary small" disabled={busy}
            onClick={() => act(() => api.del(`/sites/${siteId}/calibration`, { headers: ifMatch }), "Site calibration removed: the next runs apply none (unless the survey has its own).")}>Remove</button> : null}
        </div>
      ) : null}
      <ErrorBox error={error} title={error instanceof ApiError && error.status === 422 ? "Not accepted" : undefined} />
      {done ? <Note kind="ok">{done}</Note> : null}
    </div>
  );
}
