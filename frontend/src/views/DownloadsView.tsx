/** Downloads: every result of a run in its formats, the PDF report, and every output file. */

import { api } from "../api/client";
import type { OutputFile, Run } from "../api/types";
import { ErrorBox, Loading } from "../components/ui";
import { useLoad } from "../hooks";
import { formatBytes } from "../lib/format";
import type { SurveyContext } from "./SurveyView";

interface Product {
  title: string;
  what: string;
  path: string; // result endpoint under /runs/{id}/results
  needs: string[]; // output paths (any of them) that must exist
  formats: [string, string][]; // [query or "", label]
}

const PRODUCTS: Product[] = [
  { title: "Accuracy report", what: "PDF: check-point table, PPK quality, lever arm, volumes", path: "report.pdf", needs: ["report/accuracy_report.pdf"], formats: [["", "PDF"]] },
  { title: "Check-point residuals", what: "dE, dN, dh, |d| per point and statistics", path: "residuals", needs: ["residuals.json", "residuals.csv"], formats: [["csv", "CSV"], ["json", "JSON"], ["geojson", "GeoJSON"]] },
  { title: "GNSS trajectory", what: "PPK antenna positions with quality", path: "trajectory", needs: ["ppk/trajectory.pos"], formats: [["pos", "RTKLIB .pos"], ["csv", "CSV"], ["geojson", "GeoJSON"], ["json", "JSON"]] },
  { title: "Camera positions", what: "Antenna at each camera trigger", path: "camera-positions", needs: ["ppk/events.csv", "ppk/trajectory_events.csv"], formats: [["csv", "CSV"], ["geojson", "GeoJSON"], ["json", "JSON"]] },
  { title: "Lever arm and delay", what: "Estimated camera–antenna offset and trigger delay", path: "lever-arm", needs: ["lever_arm_delay.json"], formats: [["", "JSON"]] },
  { title: "Surface model (DSM)", what: "Cloud-optimised GeoTIFF, ellipsoidal heights", path: "dsm", needs: ["dense/dsm.tif"], formats: [["", "GeoTIFF"]] },
  { title: "Orthophoto", what: "Cloud-optimised GeoTIFF", path: "ortho", needs: ["dense/ortho.tif"], formats: [["", "GeoTIFF"]] },
  { title: "Point cloud", what: "Dense points", path: "point-cloud", needs: ["dense/points.laz", "dense/points.las"], formats: [["laz", "LAZ"], ["las", "LAS"]] },
  { title: "Stockpile volumes", what: "Cut, fill, net and area per stockpile", path: "volumes", needs: ["volumes/volumes.json"], formats: [["csv", "CSV"], ["json", "JSON"], ["geojson", "GeoJSON"]] },
];

export function DownloadsView({ run }: { ctx: SurveyContext; run: Run }) {
  const files = useLoad((signal) => api.get<OutputFile[]>(`/runs/${run.id}/results`, { signal }), [run.id]);
  if (files.error) return <ErrorBox error={files.error} />;
  if (!files.data) return <Loading what="the results" />;
  const have = new Set(files.data.map((f) => f.path));
  const url = (p: Product, fmt: string) => `/api/v1/runs/${run.id}/results/${p.path}${fmt && p.path !== "report.pdf" ? `?format=${fmt}` : ""}`;
  return (
    <div class="downloads">
      <h2 class="sr-only">Downloads</h2>
      <ul class="product-list">
        {PRODUCTS.map((p) => {
          const ok = p.needs.some((n) => have.has(n)) || (p.path === "volumes" && files.data!.some((f) => f.path.startsWith("volumes/")));
          const size = files.data!.find((f) => p.needs.includes(f.path))?.size;
          return (
            <li key={p.path} class={ok ? "card product" : "card product unavailable"}>
              <div>
                <h3 class="h4">{p.title}</h3>
                <p class="small muted">{p.what}{size ? ` · ${formatBytes(size)}` : ""}</p>
              </div>
              <div class="formats">
                {ok ? p.formats.map(([fmt, label]) => <a key={label} class="button secondary small" href={url(p, fmt)} download>{label}</a>) : <span class="small muted">not in this run</span>}
              </div>
            </li>
          );
        })}
      </ul>
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
