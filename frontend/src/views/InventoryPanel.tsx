/** The site's stockpile inventory at a date (GET /sites/{id}/inventory): volume, density, tonnes and the
 * change since each pile's previous survey, each ± 1σ, a totals row, and the CSV / XLSX downloads. */

import { useState } from "preact/hooks";
import { api } from "../api/client";
import type { Stockpile } from "../api/types";
import { ErrorBox, Field, Loading } from "../components/ui";
import { useLoad } from "../hooks";
import { inventoryCells, inventoryUrl, isIsoDate, todayUtc, type InventoryDoc, type PmText } from "../lib/inventory";

function Pm({ t }: { t: PmText }) {
  return (
    <span title={t.ci95 || undefined}>
      {t.value}
      {t.pm ? <span class="pm"> {t.pm}</span> : null}
    </span>
  );
}

export function InventoryPanel({ siteId, piles }: { siteId: string; piles: Stockpile[] | undefined }) {
  const [date, setDate] = useState(todayUtc());
  const valid = isIsoDate(date);
  const inv = useLoad(
    async (signal) => (valid ? api.get<InventoryDoc>(inventoryUrl(siteId, date, "json"), { signal }) : undefined),
    [siteId, date, valid],
  );
  const labels = new Map<string, string>();
  for (const p of piles ?? []) if (p.material && p.material_label) labels.set(p.material, p.material_label);
  const doc = inv.data;
  const rows = doc ? doc.stockpiles.map((r) => inventoryCells(r, labels)) : [];
  const total = doc ? inventoryCells(doc.totals, labels) : null;

  return (
    <div class="inventory" data-testid="inventory">
      <div class="form-row">
        <Field id="inventory-date" label="Inventory on" hint="each pile's latest survey on or before this date (UTC)">
          <input id="inventory-date" type="date" value={date} max="9999-12-31" aria-describedby="inventory-date-hint"
            onInput={(e) => setDate((e.target as HTMLInputElement).value)} />
        </Field>
        <div class="actions">
          {valid ? (
            <>
              <a class="button secondary small" href={inventoryUrl(siteId, date, "csv")} download={`inventory_${date}.csv`}>Download CSV</a>
              <a class="button secondary small" href={inventoryUrl(siteId, date, "xlsx")} download={`inventory_${date}.xlsx`}>Download XLSX</a>
            </>
          ) : (
            <span class="small warn-text">Choose a date to see the inventory.</span>
          )}
        </div>
      </div>
      <ErrorBox error={inv.error} title="The inventory could not be read" />
      {inv.loading && !doc ? <Loading what="the inventory" /> : null}
      {doc && !doc.stockpiles.length ? <p class="empty">No stockpile on this site yet: outline one in a survey's Volumes view.</p> : null}
      {doc && doc.stockpiles.length ? (
        <div class="table-wrap">
          <table class="data compact inventory-table">
            <caption class="sr-only">Stockpile inventory of {doc.site} on {doc.date}; uncertainties 1 sigma</caption>
            <thead>
              <tr>
                <th scope="col">Stockpile</th>
                <th scope="col">Material</th>
                <th scope="col">Surveyed</th>
                <th scope="col" class="num">Volume (m³)</th>
                <th scope="col" class="num">Density (t/m³)</th>
                <th scope="col" class="num">Tonnage (t)</th>
                <th scope="col" class="num">Change since last survey (m³)</th>
              </tr>
            </thead>
            <tbody>
              {rows.map((c, i) => (
                <tr key={`${c.pile}${i}`}>
                  <th scope="row">{c.pile}</th>
                  <td>{c.material || <span class="muted">–</span>}</td>
                  <td>{c.measured ? c.surveyed : <span class="muted small">{c.status}</span>}</td>
                  <td class="num"><Pm t={c.volume} /></td>
                  <td class="num">
                    <Pm t={c.density} />
                    {c.densityNote ? <span class="block small muted">{c.densityNote}</span> : null}
                  </td>
                  <td class="num"><Pm t={c.tonnes} /></td>
                  <td class="num">
                    <Pm t={c.change} />
                    {c.changeNote ? <span class="block small muted">{c.changeNote}</span> : null}
                  </td>
                </tr>
              ))}
            </tbody>
            {total ? (
              <tfoot>
                <tr class="total-row">
                  <th scope="row">Total</th>
                  <td colSpan={2} class="small muted">{total.status}</td>
                  <td class="num"><Pm t={total.volume} /></td>
                  <td class="num" />
                  <td class="num"><Pm t={total.tonnes} /></td>
                  <td class="num"><Pm t={total.change} /></td>
                </tr>
              </tfoot>
            ) : null}
          </table>
        </div>
      ) : null}
      {doc && doc.stockpiles.length ? (
        <details class="small">
          <summary>How the figures are made</summary>
          <ul>
            {doc.notes.map((n) => <li key={n}>{n}</li>)}
            <li>± is one standard deviation (1σ); hover a figure for its 95 % interval.</li>
          </ul>
        </details>
      ) : null}
    </div>
  );
}
