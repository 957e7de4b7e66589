import { useState } from "preact/hooks";
import { api, setCsrfToken } from "../api/client";
import type { LoginResult, Me } from "../api/types";
import { ErrorBox } from "../components/ui";

export function LoginView({ onLogin }: { onLogin: (me: Me) => void }) {
  const [email, setEmail] = useState("");
  const [password, setPassword] = useState("");
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);

  const submit = async (e: Event) => {
    e.preventDefault();
    setBusy(true);
    setError(null);
    try {
      const r = await api.post<LoginResult>("/auth/login", { email: email.trim(), password });
      setCsrfToken(r.csrf_token);
      onLogin(await api.get<Me>("/auth/me"));
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };

  return (
    <main id="main" class="login" tabIndex={-1}>
      <form class="card login-card" onSubmit={submit} aria-labelledby="login-title">
        <h1 id="login-title">Sign in to Georef</h1>
        <p class="muted">Drone surveys of your sites: accuracy and stockpile volumes.</p>
        <div class="field">
          <label for="email">E-mail</label>
          <input id="email" type="email" autoComplete="username" required value={email} onInput={(e) => setEmail((e.target as HTMLInputElement).value)} />
        </div>
        <div class="field">
          <label for="password">Password</label>
          <input id="password" type="password" autoComplete="current-password" required value={password} onInput={(e) => setPassword((e.target as HTMLInputElement).value)} />
        </div>
        <ErrorBox error={error} />
        <button type="submit" class="primary" disabled={busy}>{busy ? "Signing in…" : "Sign in"}</button>
      </form>
    </main>
  );
}
