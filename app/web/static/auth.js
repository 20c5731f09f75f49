// The admin token of the farm and cells pages: typed in, or given as #token=… in the link
// (a kiosk screen); kept in this tab's session storage only and sent as a Bearer header.
const Auth = (() => {
  const KEY = "vantage-admin-token";
  const hash = new URLSearchParams(location.hash.slice(1));
  if (hash.get("token")) {
    sessionStorage.setItem(KEY, hash.get("token"));
    history.replaceState(null, "", location.pathname + location.search); // out of the address bar
  }
  const $ = (id) => document.getElementById(id);

  function token() { return sessionStorage.getItem(KEY); }

  async function api(path, options = {}) {
    const headers = { ...(options.headers || {}), Authorization: `Bearer ${token()}` };
    const r = await fetch(path, { ...options, headers, cache: "no-store" });
    if (r.status === 401 || r.status === 403) {
      signOut(r.status === 401 ? "That token was not accepted." : "That is not the admin token.");
      throw new Error("not signed in");
    }
    return r;
  }

  function signOut(error) {
    sessionStorage.removeItem(KEY);
    $("board").hidden = true;
    $("signed-in").hidden = true;
    $("signin").hidden = false;
    $("signin-error").textContent = error || "";
    for (const el of document.querySelectorAll("[data-clear]")) el.innerHTML = "";
  }

  function start(load) {
    $("signin").addEventListener("submit", (e) => {
      e.preventDefault();
      sessionStorage.setItem(KEY, $("token").value.trim());
      $("token").value = "";
      begin();
    });
    $("signout").addEventListener("click", () => signOut(""));
    async function begin() {
      if (!token()) return signOut("");
      $("signin").hidden = true;
      try {
        await load();
        $("signin-error").textContent = "";
        $("board").hidden = false;
        $("signed-in").hidden = false;
      } catch (e) {
        if (e.message !== "not signed in") $("signin-error").textContent = `Could not load: ${e.message}`;
      }
    }
    begin();
  }
  return { api, start, token };
})();
