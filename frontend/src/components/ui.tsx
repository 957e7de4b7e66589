/** Small shared pieces: status pills, progress bars, messages, tabs, spinners. */

import type { ComponentChildren } from "preact";
import { useRef } from "preact/hooks";

const STATE_LABEL: Record<string, string> = {
  queued: "queued", running: "processing", succeeded: "done", failed: "failed", cancelled: "cancelled",
  pending: "waiting", skipped: "skipped", unavailable: "not available", none: "not processed",
};

export function StatePill({ state }: { state: string }) {
  return <span class={`pill pill-${state}`}>{STATE_LABEL[state] ?? state}</span>;
}

export function ProgressBar({ value, max, label, text }: { value: number; max: number; label: string; text?: string }) {
  const pct = max > 0 ? Math.min(100, Math.max(0, (100 * value) / max)) : 0;
  return (
    <div class="progress" role="progressbar" aria-label={label} aria-valuemin={0} aria-valuemax={100} aria-valuenow={Math.round(pct)} aria-valuetext={text ?? `${Math.round(pct)} %`}>
      <div class="progress-fill" style={{ width: `${pct}%` }} />
    </div>
  );
}

export function ErrorBox({ error, title }: { error: Error | string | null | undefined; title?: string }) {
  if (!error) return null;
  return (
    <div class="msg msg-error" role="alert">
      {title ? <strong>{title}: </strong> : null}
      {typeof error === "string" ? error : error.message}
    </div>
  );
}

export function Note({ kind = "info", children }: { kind?: "info" | "warning" | "error" | "ok"; children: ComponentChildren }) {
  return <div class={`msg msg-${kind}`}>{children}</div>;
}

export function Loading({ what }: { what: string }) {
  return (
    <p class="loading" aria-live="polite">
      <span class="spinner" aria-hidden="true" /> Loading {what}…
    </p>
  );
}

export interface TabDef {
  id: string;
  label: string;
  href: string;
  disabled?: boolean;
}

/** Navigation tabs (links: each view has its own URL); arrow keys move between them. */
export function Tabs({ tabs, current, label }: { tabs: TabDef[]; current: string; label: string }) {
  const ref = useRef<HTMLElement>(null);
  const onKey = (e: KeyboardEvent) => {
    if (e.key !== "ArrowRight" && e.key !== "ArrowLeft") return;
    const links = Array.from(ref.current?.querySelectorAll<HTMLAnchorElement>("a") ?? []);
    const i = links.indexOf(document.activeElement as HTMLAnchorElement);
    if (i < 0) return;
    const j = (i + (e.key === "ArrowRight" ? 1 : -1) + links.length) % links.length;
    links[j].focus();
    e.preventDefault();
  };
  return (
    <nav class="tabs" aria-label={label} ref={ref} onKeyDown={onKey}>
      {tabs.map((t) => (
        <a key={t.id} href={t.href} class={t.id === current ? "tab active" : "tab"} aria-current={t.id === current ? "page" : undefined}>
          {t.label}
        </a>
      ))}
    </nav>
  );
}

export function Field({ label, hint, children, id }: { label: string; hint?: string; children: ComponentChildren; id: string }) {
  return (
    <div class="field">
      <label for={id}>{label}</label>
      {children}
      {hint ? <small id={`${id}-hint`} class="hint">{hint}</small> : null}
    </div>
  );
}

export function Figure({ label, value, unit, title }: { label: string; value: string; unit?: string; title?: string }) {
  return (
    <div class="figure" title={title}>
      <div class="figure-value">
        {value}
        {unit ? <span class="figure-unit"> {unit}</span> : null}
      </div>
      <div class="figure-label">{label}</div>
    </div>
  );
}
