/** "Open in QGIS / GIS" on a run's Downloads tab: the run's tile layers (GET /runs/{id}/tiles), a read-only
 * tile token made on request (POST /tokens/tile, shown once, expiring) and the WMTS capabilities URL and XYZ
 * templates with it, each with a copy button. */

import { useRef, useState } from "preact/hooks";
import { api } from "../api/client";
import type { Run } from "../api/types";
import { ErrorBox, Loading } from "../components/ui";
import { useLoad } from "../hooks";
import { clampTokenDays, expiryText, TILE_TOKEN_MAX_DAYS, wmtsCapabilitiesUrl, xyzUrl, type TileLayers, type TileToken } from "../lib/gisLinks";

function CopyField({ id, label, value }: { id: string; label: string; value: string }) {
  const ref = useRef<HTMLInputElement>(null);
  const [said, setSaid] = useState("");
  const copy = async () => {
    try {
      await navigator.clipboard.writeText(value);
      setSaid("Copied");
    } catch {
      // no clipboard API (a plain-http page): select it for Ctrl+C
      ref.current?.select();
      let ok = false;
      try {
        ok = document.execCommand("copy");
      } catch {
        ok = false;
      }
      setSaid(ok ? "Copied" : "Selected: press Ctrl+C to copy");
    }
    setTimeout(() => setSaid(""), 4000);
  };
  return (
    <div class="copy-field">
      <label for={id} class="small">{label}</label>
      <div class="copy-row">
        <input id={id} ref={ref} readOnly value={value} spellcheck={false} onFocus={(e) => (e.target as HTMLInputElement).select()} />
        <button type="button" class="secondary small" onClick={copy} aria-label={`Copy ${label}`}>Copy</button>
        <span class="small muted" aria-live="polite">{said}</span>
      </div>
    </div>
  );
}

export function GisPanel({ run }: { run: Run }) {
  const layers = useLoad((signal) => api.maybe<TileLayers>(`/runs/${run.id}/tiles`, { signal }), [run.id]);
  const [days, setDays] = useState(30);
  const [token, setToken] = useState<TileToken | null>(null);
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);
  const [revoked, setRevoked] = useState(false);
  const origin = typeof location !== "undefined" ? location.origin : "";

  const create = async () => {
    setBusy(true);
    setError(null);
    try {
      setToken(await api.post<TileToken>("/tokens/tile", { name: `QGIS · run ${run.number}`, expires_in_days: clampTokenDays(days) }));
    } catch (e) {
      setError(e as Error);
    } finally {
      setBusy(false);
    }
  };

  const revoke = async () => {
    if (!token) return;
    setBusy(true);
    setError(null);
    try {
      await api.del(`/tokens/${encodeURIComponent(token.id)}`);
      setRevoked(true);
    } catch (e) {
      setError(e as Error);
    } finally {
      setBusy(false);
    }
  };

  const list = layers.data?.layers ?? [];
  return (
    <section class="card gis-panel" aria-labelledby="gis-title" data-testid="gis-panel">
      <h3 id="gis-title" class="h4">Open in QGIS / GIS</h3>
      {layers.error ? <ErrorBox error={layers.error} /> : null}
      {layers.loading && !layers.data ? <Loading what="the map layers" /> : null}
      {layers.data !== undefined && !list.length ? <p class="small muted">This run has no map layers (orthophoto, DSM or difference to design) yet.</p> : null}
      {list.length ? (
        <>
          <p class="small">
            Map layers of run {run.number}: {list.map((l, i) => <span key={l.name}>{i ? ", " : ""}<strong>{l.name}</strong> ({l.title}, zoom {l.min_zoom}–{l.max_zoom})</span>)}.
            {" "}Web Mercator tiles for display; measure on the GeoTIFFs above.
          </p>
          {!token ? (
            <div class="form-row">
              <div class="field">
                <label for="tile-token-days">Token valid for (days, 1–{TILE_TOKEN_MAX_DAYS})</label>
                <input id="tile-token-days" type="number" min={1} max={TILE_TOKEN_MAX_DAYS} step={1} class="narrow" value={days}
                  onInput={(e) => setDays(Number((e.target as HTMLInputElement).value))} />
              </div>
              <button type="button" class="primary small" disabled={busy} onClick={create}>{busy ? "Creating…" : "Create a tile token"}</button>
              <p class="small muted">A read-only token that only reads map tiles of your sites; it travels in the URL, so share it like a password.</p>
            </div>
          ) : (
            <div class="gis-links">
              <p class="msg msg-warning small" role="status">
                Token <code>{token.prefix}…</code> {revoked ? "revoked: the URLs below no longer work" : `${expiryText(token.expires_at)}. It is shown only now: copy the URLs before leaving this page`}.
              </p>
              <CopyField id="wmts-url" label="WMTS capabilities URL" value={wmtsCapabilitiesUrl(origin, run.id, token.token)} />
              {list.map((l) => <CopyField key={l.name} id={`xyz-${l.name}`} label={`XYZ tiles: ${l.name} (max zoom ${l.max_zoom})`} value={xyzUrl(origin, l, token.token)} />)}
              <p class="small">
                <strong>QGIS:</strong> Layer › Add Layer › Add WMS/WMTS Layer › New, paste the WMTS URL, Connect and choose a layer; or in the
                Browser panel, XYZ Tiles › New Connection, paste an XYZ URL and set its max zoom.
              </p>
              <div class="actions">
                <button type="button" class="secondary small" onClick={() => { setToken(null); setRevoked(false); }}>Make another token</button>
                {!revoked ? <button type="button" class="link danger small" disabled={busy} onClick={revoke}>Revoke this token now</button> : null}
              </div>
            </div>
          )}
          <ErrorBox error={error} />
        </>
      ) : null}
    </section>
  );
}
