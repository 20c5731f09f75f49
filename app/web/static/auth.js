// The token of the farm and cells pages: the admin's or a viewer's (read-only), typed in, or
// made from a one-time sign-in code given as #code=… in a kiosk's link (POST /signin-codes).
// Kept in this tab's session storage only and sent as a Bearer header; no token is ever read
// from or left in the address.
const Auth = (() => {
  const KEY = "vantage-token";
  const $ = (id) => document.getElementById(id);
  const hash = new URLSearchParams(location.hash.slice(1));
  const code = hash.get("code");
  if (hash.has("code") || hash.has("token")) {
    history.replaceState(null, "", location.pathname + location.search); // out of the address bar
  }

  function token() { return sessionStorage.getItem(KEY); }

  async function redeem() {
    if (!code) return;
    const r = await fetch("/signin-codes/redeem", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ code }),
      cache: "no-store",
    });
    if (r.ok) sessionStorage.setItem(KEY, (await r.json()).token);
    else throw new Error("That sign-in link was used already or has expired.");
  }

  // 401 signs out; 403 signs out while signing in (a token that may not read the board) and
  // is the caller's to show once the board is up (a viewer asking for what it may not do)
  async function api(path, options = {}) {
    const headers = { ...(options.headers || {}), Authorization: `Bearer ${token()}` };
    const r = await fetch(path, { ...options, headers, cache: "no-store" });
    if (r.status === 401 || (r.status === 403 && $("board").hidden)) {
      signOut(r.status === 401 ? "That token was not accepted." : "That token may not read this board.");
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
    redeem().then(begin, (e) => signOut(e.message));
  }
  return { api, start, token };
})();
