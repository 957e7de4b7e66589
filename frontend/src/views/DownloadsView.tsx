/** Downloads: every result of a run in its formats (the products the steps' specs declare, GET /steps), the
 * PDF report, and every output file. */

import { api } from "../api/client";
import type { OutputFile, Run } from "../api/types";
import { ErrorBox, Loading } from "../components/ui";
import { useLoad } from "../hooks";
import { formatBytes } from "../lib/format";
import { loadSteps, productsOf, type StepProduct } from "../lib/steps";
import { GisPanel } from "./GisPanel";
import type { SurveyContext } from "./surveyContext";

export function DownloadsView({ run }: { ctx: SurveyContext; run: Run }) {
  const files = useLoad((signal) => api.get<OutputFile[]>(`/runs/${run.id}/results`, { signal }), [run.id]);
  const steps = useLoad((signal) => loadSteps(signal), []);
  if (files.error || steps.error) return <ErrorBox error={(files.error ?? steps.error)!} />;
  if (!files.data || !steps.data) return <Loading what="the results" />;
  const have = new Set(files.data.map((f) => f.path));
  const products = productsOf(steps.data);
  const url = (p: StepProduct, fmt: string) => `/api/v1/runs/${run.id}/results/${p.endpoint}${fmt ? `?format=${fmt}` : ""}`;
  return (
    <div class="downloads">
      <h2 class="sr-only">Downloads</h2>
      <ul class="product-list">
        {products.map((p) => {
          const ok = p.needs.some((n) => have.has(n));
          const size = files.data!.find((f) => p.needs.includes(f.path))?.size;
          return (
            <li key={p.endpoint} class={ok ? "card product" : "card product unavailable"}>
              <div>
                <h3 class="h4">{p.title}</h3>
                <p class="small muted">{p.description}{size ? ` · ${formatBytes(size)}` : ""}</p>
              </div>
              <div class="formats">
                {ok ? p.formats.map(([fmt, label]) => <a key={label} class="button secondary small" href={url(p, fmt)} download>{label}</a>) : <span class="small muted">not in this run</span>}
              </div>
            </li>
          );
        })}
      </ul>
      <GisPanel run={run} />
      <details>
        <summary>All {files.data.length} output files</summary>
        <div class="table-wrap">
          <table class="data compact">
            <thead><tr><th scope="col">File</th><th scope="col">Step</th><th scope="col" class="num">Size</th><th scope="col">SHA-256</th></tr></thead>
            <tbody>
              {files.data.map((f) => (
                <tr key={f.path}>
                  <td><a href={f.url} download>{f.path}</a></td>
                  <td>{f.step_name}</td>
                  <td class="num">{formatBytes(f.size)}</td>
                  <td><code class="small">{f.sha256.slice(0, 12)}…</code></td>
                </tr>
              ))}
            </tbody>
          </table>
        </div>
      </details>
    </div>
  );
}
