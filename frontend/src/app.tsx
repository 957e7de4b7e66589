/** The application shell: who is signed in, the header, and which view the URL asks for. */

import { useEffect, useState } from "preact/hooks";
import { ApiError, api, setCsrfToken, setUnauthorizedHandler } from "./api/client";
import type { Me } from "./api/types";
import { Loading } from "./components/ui";
import { href, navigate, useRoute } from "./router";
import { LoginView } from "./views/LoginView";
import { SitesView } from "./views/SitesView";
import { SiteView } from "./views/SiteView";
import { SurveyView } from "./views/SurveyView";

export function App() {
  const route = useRoute();
  const [me, setMe] = useState<Me | null | undefined>(undefined);

  useEffect(() => {
    setUnauthorizedHandler(() => setMe(null));
    api
      .get<Me>("/auth/me")
      .then((m) => {
        setCsrfToken(m.csrf_token);
        setMe(m);
      })
      .catch((e) => {
        if (!(e instanceof ApiError) || e.status === 401 || e.status === 403) setMe(null);
        else setMe(null);
      });
  }, []);

  // Move focus to the main heading on every view change (screen readers announce the new page).
  useEffect(() => {
    const h = document.querySelector<HTMLElement>("main h1");
    if (h) {
      h.setAttribute("tabindex", "-1");
      h.focus({ preventScroll: true });
    }
  }, [route.parts.join("/"), me === null]);

  if (me === undefined) return <main id="main"><Loading what="Georef" /></main>;

  if (me === null) {
    return (
      <LoginView
        onLogin={(m) => {
          setCsrfToken(m.csrf_token);
          setMe(m);
          if (route.parts[0] === "login") navigate(href(), true);
        }}
      />
    );
  }

  const logout = async () => {
    try {
      await api.post("/auth/logout");
    } finally {
      setCsrfToken(null);
      setMe(null);
    }
  };

  const [section, id, sub] = route.parts;
  let view;
  if (section === "sites" && id) view = <SiteView siteId={id} me={me} />;
  else if (section === "surveys" && id) view = <SurveyView surveyId={id} tab={sub ?? ""} query={route.query} me={me} />;
  else view = <SitesView me={me} />;

  return (
    <>
      <a class="skip" href="#main" onClick={(e) => { e.preventDefault(); document.getElementById("main")?.focus(); }}>Skip to content</a>
      <header class="top">
        <a class="brand" href={href()}>
          <svg viewBox="0 0 24 24" width="22" height="22" aria-hidden="true"><path d="M12 2 3 7v10l9 5 9-5V7z" fill="none" stroke="currentColor" stroke-width="2" /><circle cx="12" cy="12" r="3" fill="currentColor" /></svg>
          Georef
        </a>
        <span class="org">{me.organisation.name}</span>
        <span class="spacer" />
        <span class="user" title={me.user.email}>{me.user.name || me.user.email}</span>
        <button type="button" class="ghost" onClick={logout}>Sign out</button>
      </header>
      <main id="main" tabIndex={-1}>{view}</main>
    </>
  );
}
