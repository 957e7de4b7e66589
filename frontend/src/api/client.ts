/**
 * The REST client: same-origin fetch with the session cookie, the CSRF header on unsafe methods,
 * RFC 9457 problem details turned into ApiError with the server's own words.
 */

export const API_BASE = "/api/v1";

export class ApiError extends Error {
  constructor(
    public status: number,
    message: string,
    public problem: Record<string, any> | null = null,
  ) {
    super(message);
  }
}

let csrfToken: string | null = null;
let onUnauthorized: (() => void) | null = null;

export function setCsrfToken(t: string | null): void {
  csrfToken = t;
}

export function setUnauthorizedHandler(f: () => void): void {
  onUnauthorized = f;
}

function cookie(name: string): string | null {
  if (typeof document === "undefined") return null;
  const m = document.cookie.split(/;\s*/).find((c) => c.startsWith(name + "="));
  return m ? decodeURIComponent(m.slice(name.length + 1)) : null;
}

export function csrfHeader(): Record<string, string> {
  const t = csrfToken ?? cookie("georef_csrf");
  return t ? { "X-CSRF-Token": t } : {};
}

export interface RequestOptions {
  json?: unknown;
  body?: BodyInit;
  headers?: Record<string, string>;
  signal?: AbortSignal;
  query?: Record<string, string | number | boolean | null | undefined>;
}

export function apiUrl(path: string, query?: RequestOptions["query"]): string {
  let url = path.startsWith("/api/") ? path : API_BASE + path;
  if (query) {
    const q = Object.entries(query)
      .filter(([, v]) => v !== null && v !== undefined)
      .map(([k, v]) => `${encodeURIComponent(k)}=${encodeURIComponent(String(v))}`)
      .join("&");
    if (q) url += (url.includes("?") ? "&" : "?") + q;
  }
  return url;
}

async function errorOf(res: Response): Promise<ApiError> {
  let problem: Record<string, any> | null = null;
  let message = `${res.status} ${res.statusText}`;
  try {
    const text = await res.text();
    try {
      problem = JSON.parse(text);
      if (problem && typeof problem.detail === "string") message = problem.detail;
      else if (problem && typeof problem.title === "string") message = problem.title;
    } catch {
      if (text && text.length < 300) message = text;
    }
  } catch {
    /* body unreadable: keep the status line */
  }
  return new ApiError(res.status, message, problem);
}

export async function request(method: string, path: string, opts: RequestOptions = {}): Promise<Response> {
  const headers: Record<string, string> = { Accept: "application/json", ...(opts.headers ?? {}) };
  let body = opts.body;
  if (opts.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(opts.json);
  }
  if (!["GET", "HEAD", "OPTIONS"].includes(method)) Object.assign(headers, csrfHeader());
  let res: Response;
  try {
    res = await fetch(apiUrl(path, opts.query), { method, headers, body, credentials: "same-origin", signal: opts.signal });
  } catch (e) {
    if ((e as Error).name === "AbortError") throw e;
    throw new ApiError(0, "The server cannot be reached: check the connection.");
  }
  if (!res.ok) {
    const err = await errorOf(res);
    if (res.status === 401 && onUnauthorized && !path.startsWith("/auth/login")) onUnauthorized();
    throw err;
  }
  return res;
}

async function json<T>(res: Response): Promise<T> {
  if (res.status === 204) return undefined as T;
  const text = await res.text();
  return (text ? JSON.parse(text) : undefined) as T;
}

export const api = {
  get: async <T>(path: string, opts?: RequestOptions) => json<T>(await request("GET", path, opts)),
  post: async <T>(path: string, payload?: unknown, opts?: RequestOptions) => json<T>(await request("POST", path, { ...opts, json: payload ?? {} })),
  patch: async <T>(path: string, payload: unknown, opts?: RequestOptions) => json<T>(await request("PATCH", path, { ...opts, json: payload })),
  put: async <T>(path: string, opts?: RequestOptions) => json<T>(await request("PUT", path, opts)),
  del: async (path: string, opts?: RequestOptions) => {
    await request("DELETE", path, opts);
  },
  /** GET with the response's ETag (for If-Match on a later PATCH/DELETE). */
  getWithEtag: async <T>(path: string, opts?: RequestOptions): Promise<{ data: T; etag: string | null }> => {
    const res = await request("GET", path, opts);
    return { data: await json<T>(res), etag: res.headers.get("ETag") };
  },
  /** GET that answers null instead of throwing on 404/409 (a result the run has not produced). */
  maybe: async <T>(path: string, opts?: RequestOptions): Promise<T | null> => {
    try {
      return await json<T>(await request("GET", path, opts));
    } catch (e) {
      if (e instanceof ApiError && (e.status === 404 || e.status === 409)) return null;
      throw e;
    }
  },
};

/**
 * Every item of a paginated list endpoint ({items, total, limit, offset}: the API's conventions), page by
 * page (`pageSize` at most 500), up to `max` items.
 */
export async function getAllPages<T>(path: string, opts: { query?: RequestOptions["query"]; signal?: AbortSignal; pageSize?: number; max?: number } = {}): Promise<T[]> {
  const limit = Math.max(1, Math.min(500, opts.pageSize ?? 500));
  const max = opts.max ?? 100000;
  const out: T[] = [];
  for (let offset = 0; out.length < max; ) {
    const page = await api.get<{ items: T[]; total: number; limit: number; offset: number }>(path, { query: { ...(opts.query ?? {}), limit, offset }, signal: opts.signal });
    out.push(...page.items);
    offset += page.items.length;
    if (!page.items.length || offset >= page.total) break;
  }
  return out.slice(0, max);
}

/** Run async jobs over items with at most `limit` in flight. */
export async function mapLimit<T, R>(items: T[], limit: number, f: (x: T, i: number) => Promise<R>): Promise<R[]> {
  const out: R[] = new Array(items.length);
  let next = 0;
  const worker = async () => {
    while (next < items.length) {
      const i = next++;
      out[i] = await f(items[i], i);
    }
  };
  await Promise.all(Array.from({ length: Math.min(limit, items.length) }, worker));
  return out;
}
