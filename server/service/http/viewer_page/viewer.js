// The sphrender viewer: live service status and a demo session orbited with the mouse.
//
// Plain JavaScript, no framework. It talks to the same HTTP API as any client:
//   GET  /v1/status, /v1/info                       every second / once
//   POST /v1/demo/sessions {"image": {...}}          a session of the built-in weld bead
//   POST /v1/sessions/{id}/frames?format=png         body {"scene": {"camera": {"eye": [...]}}}:
//        a per-frame camera override, merged onto the session's scene like an .npz frame's
//   DELETE /v1/sessions/{id}                         when the page goes away
//   GET  /v1/sessions/{id}/latest                    another session's latest image (any
//        transport), polled with If-None-Match while that session is the one watched
// With a token, open /?token=...: the server sets a cookie that authorises these requests (the
// X-Sphrender-Viewer header is required with it on POST and DELETE).
//
// Query parameters: format (an image encoding the browser can show: png, or jpeg where the
// server offers it; default png), width and height of the demo frames (default 480 x 270),
// spin=1 (orbit continuously).
"use strict";

(() => {
  const params = new URLSearchParams(location.search);
  const HEADERS = { "X-Sphrender-Viewer": "1" };
  // Encodings a browser decodes into a canvas; exr and raw frames are for other clients.
  const DISPLAYABLE = ["png", "jpeg"];
  const number = (text, fallback) => {
    const value = Number.parseInt(text ?? "", 10);
    return Number.isFinite(value) && value > 0 ? value : fallback;
  };
  const state = {
    format: params.get("format") || "png",
    width: number(params.get("width"), 480),
    height: number(params.get("height"), 270),
    session: null,
    orbit: null,
    inFlight: null,
    dirty: false,
    frames: 0,
    statusUpdates: 0,
    stopped: false,
    lastBody: null,
    timer: null,
    watch: null, // the id of the session watched instead of the demo, or null
    watchTag: null,
    watchTimer: null,
  };
  const $ = (id) => document.getElementById(id);

  function show(id, value, text) {
    const element = $(id);
    element.dataset.value = String(value);
    element.textContent = text === undefined ? String(value) : text;
  }

  function showError(message) {
    const element = $("error");
    element.hidden = !message;
    element.textContent = message || "";
  }

  async function api(method, path, body) {
    const init = { method, headers: { ...HEADERS }, credentials: "same-origin" };
    if (body !== undefined) {
      init.body = JSON.stringify(body);
      init.headers["Content-Type"] = "application/json";
    }
    const response = await fetch(path, init);
    if (!response.ok) {
      let message = `${response.status} ${response.statusText}`;
      try {
        const error = await response.json();
        message = `${error.field ? error.field + ": " : ""}${error.error} (${error.code})`;
      } catch (_ignored) {
        // not a JSON error body: keep the status line
      }
      const failure = new Error(message);
      failure.status = response.status;
      throw failure;
    }
    return response;
  }

  // -- status ------------------------------------------------------------------------------

  async function refreshStatus() {
    const doc = await (await api("GET", "/v1/status")).json();
    const badge = $("state");
    badge.textContent = doc.state;
    badge.className = "badge " + (doc.ready ? "ready" : "down");
    show("renderer", doc.renderer);
    show("sessions-http", doc.sessions.http);
    show("sessions-stream", doc.sessions.stream);
    show("frames-per-s", doc.recent.frames_per_s);
    show("queue-depth", doc.queue_depth);
    show("in-flight", doc.in_flight);
    for (const key of ["p50_ms", "p90_ms", "p99_ms"]) {
      show(key.replace("_", "-"), doc.recent[key], `${doc.recent[key]} ms`);
    }
    show("latency-frames", doc.recent.frames);
    show("frames-image", doc.frames_total.image);
    show("frames-error", doc.frames_total.error);
    show("frames-dropped", doc.frames_total.dropped);
    listSessions(doc.session_list || []);
    state.statusUpdates += 1;
    document.body.dataset.statusUpdates = String(state.statusUpdates);
    return doc;
  }

  async function pollStatus() {
    try {
      await refreshStatus();
    } catch (error) {
      const badge = $("state");
      badge.textContent = "unreachable";
      badge.className = "badge down";
    }
  }

  // -- watching another session ----------------------------------------------------------------

  function listSessions(sessions) {
    const select = $("source");
    const wanted = sessions.filter((s) => !s.demo && s.latest_format);
    const ids = new Set(wanted.map((s) => s.id));
    for (const option of [...select.options]) {
      if (option.value !== "demo" && !ids.has(option.value)) option.remove();
    }
    const present = new Set([...select.options].map((o) => o.value));
    for (const s of wanted) {
      if (present.has(s.id)) continue;
      const option = document.createElement("option");
      option.value = s.id;
      option.textContent = `${s.transport} ${s.id.slice(0, 8)} (${s.latest_format})`;
      select.append(option);
    }
  }

  async function pollWatched() {
    const id = state.watch;
    if (!id || state.stopped) return;
    try {
      const headers = { ...HEADERS };
      if (state.watchTag) headers["If-None-Match"] = state.watchTag;
      const response = await fetch(`/v1/sessions/${id}/latest`, {
        headers,
        cache: "no-store",
        credentials: "same-origin",
      });
      if (id !== state.watch) return;
      if (response.status === 200) {
        const blob = await response.blob();
        await draw(blob);
        state.watchTag = response.headers.get("ETag");
        const canvas = $("live");
        canvas.dataset.source = id;
        canvas.dataset.image = response.headers.get("X-Sphrender-Image") || "";
        $("frame-info").textContent =
          `session ${id.slice(0, 8)}, image ${canvas.dataset.image}: ` +
          `${canvas.width}x${canvas.height}, ${blob.size} bytes`;
        showError("");
      } else if (response.status !== 304) {
        const error = await response.json();
        showError(`${error.field ? error.field + ": " : ""}${error.error}`);
      }
    } catch (error) {
      showError(String(error.message || error));
    }
  }

  async function watch(id) {
    state.watch = id === "demo" ? null : id;
    state.watchTag = null;
    clearInterval(state.watchTimer);
    $("hint").hidden = state.watch !== null;
    $("source").value = id;
    if (state.watch) {
      if (state.inFlight) await state.inFlight;
      state.watchTimer = setInterval(pollWatched, 250);
      await pollWatched();
    } else {
      $("live").dataset.source = "demo";
      await renderFrame();
    }
  }

  // -- the demo session and its camera -------------------------------------------------------

  function orbitFrom(camera) {
    const [ex, ey, ez] = camera.eye;
    const [tx, ty, tz] = camera.target;
    const [dx, dy, dz] = [ex - tx, ey - ty, ez - tz];
    const radius = Math.hypot(dx, dy, dz);
    return {
      target: camera.target,
      radius,
      minRadius: radius * 0.2,
      maxRadius: radius * 5,
      yaw: Math.atan2(dx, dz),
      pitch: Math.asin(dy / radius),
    };
  }

  function eye() {
    const o = state.orbit;
    const round = (v) => Math.round(v * 1e6) / 1e6;
    return [
      round(o.target[0] + o.radius * Math.cos(o.pitch) * Math.sin(o.yaw)),
      round(o.target[1] + o.radius * Math.sin(o.pitch)),
      round(o.target[2] + o.radius * Math.cos(o.pitch) * Math.cos(o.yaw)),
    ];
  }

  async function openDemo() {
    const response = await api("POST", "/v1/demo/sessions", {
      image: { width: state.width, height: state.height },
    });
    const created = await response.json();
    state.session = created.id;
    state.orbit = state.orbit || orbitFrom(created.scene.camera);
  }

  // The frame's pixels, as the test reads them: FNV-1a over the RGBA bytes, and the mean.
  function summarise(pixels) {
    let hash = 0x811c9dc5;
    const sums = [0, 0, 0, 0];
    for (let i = 0; i < pixels.length; i += 1) {
      hash = Math.imul(hash ^ pixels[i], 16777619) >>> 0;
      sums[i & 3] += pixels[i];
    }
    const count = pixels.length / 4;
    return { fnv1a: hash.toString(16).padStart(8, "0"), mean: sums.map((s) => s / count) };
  }

  async function draw(blob) {
    const bitmap = await createImageBitmap(blob, {
      colorSpaceConversion: "none",
      premultiplyAlpha: "none",
    });
    const canvas = $("live");
    canvas.width = bitmap.width;
    canvas.height = bitmap.height;
    const context = canvas.getContext("2d", { willReadFrequently: true });
    context.clearRect(0, 0, canvas.width, canvas.height);
    context.drawImage(bitmap, 0, 0);
    bitmap.close();
    const summary = summarise(context.getImageData(0, 0, canvas.width, canvas.height).data);
    canvas.dataset.fnv1a = summary.fnv1a;
    canvas.dataset.mean = summary.mean.map((m) => m.toFixed(3)).join(",");
    return summary;
  }

  async function renderFrame() {
    if (state.watch) return; // another session is shown
    if (state.inFlight || state.stopped) {
      state.dirty = true;
      return;
    }
    state.dirty = false;
    state.inFlight = (async () => {
      try {
        if (!state.session) await openDemo();
        const body = JSON.stringify({ scene: { camera: { eye: eye() } } });
        const path = `/v1/sessions/${state.session}/frames?format=${state.format}`;
        const response = await fetch(path, {
          method: "POST",
          headers: { ...HEADERS, "Content-Type": "application/json" },
          credentials: "same-origin",
          body,
        });
        if (response.status === 404) {
          state.session = null; // expired (limits.session_idle_timeout_s): open a new one
          state.dirty = true;
          return;
        }
        if (!response.ok) {
          const error = await response.json();
          throw new Error(`${error.field ? error.field + ": " : ""}${error.error}`);
        }
        const blob = await response.blob();
        await draw(blob);
        state.lastBody = body;
        state.frames += 1;
        const canvas = $("live");
        canvas.dataset.frames = String(state.frames);
        canvas.dataset.session = state.session;
        canvas.dataset.source = "demo";
        const timing = response.headers.get("Server-Timing") || "";
        const render = timing
          .split(",")
          .map((part) => part.trim().split(";dur="))
          .filter(([name]) => name !== "queue" && name !== "encode")
          .reduce((sum, [, ms]) => sum + Number(ms || 0), 0);
        $("frame-info").textContent =
          `frame ${state.frames}: ${canvas.width}x${canvas.height} ${state.format}, ` +
          `${blob.size} bytes, rendered in ${render.toFixed(0)} ms`;
        showError("");
      } catch (error) {
        showError(String(error.message || error));
      }
    })();
    await state.inFlight;
    state.inFlight = null;
    if (!state.stopped && (state.dirty || $("spin").checked)) {
      if ($("spin").checked) state.orbit.yaw += 0.03;
      requestAnimationFrame(renderFrame);
    }
  }

  function bindMouse() {
    const canvas = $("live");
    let last = null;
    canvas.addEventListener("pointerdown", (event) => {
      last = [event.clientX, event.clientY];
      canvas.setPointerCapture(event.pointerId);
      canvas.classList.add("dragging");
    });
    canvas.addEventListener("pointermove", (event) => {
      if (!last || !state.orbit || state.watch) return;
      const [dx, dy] = [event.clientX - last[0], event.clientY - last[1]];
      last = [event.clientX, event.clientY];
      state.orbit.yaw -= dx * 0.01;
      state.orbit.pitch = Math.min(1.45, Math.max(-1.45, state.orbit.pitch + dy * 0.01));
      renderFrame();
    });
    const end = () => {
      last = null;
      canvas.classList.remove("dragging");
    };
    canvas.addEventListener("pointerup", end);
    canvas.addEventListener("pointercancel", end);
    canvas.addEventListener(
      "wheel",
      (event) => {
        if (!state.orbit || state.watch) return;
        event.preventDefault();
        const o = state.orbit;
        o.radius = Math.min(o.maxRadius, Math.max(o.minRadius, o.radius * Math.exp(event.deltaY * 1e-3)));
        renderFrame();
      },
      { passive: false },
    );
    $("spin").addEventListener("change", () => renderFrame());
    $("source").addEventListener("change", (event) => watch(event.target.value));
  }

  async function chooseFormats() {
    const info = await (await api("GET", "/v1/info")).json();
    const offered = (info.formats || ["png"]).filter((f) => DISPLAYABLE.includes(f));
    const select = $("format");
    for (const format of offered) {
      const option = document.createElement("option");
      option.value = option.textContent = format;
      select.append(option);
    }
    if (!offered.includes(state.format)) {
      showError(`format ${state.format} cannot be shown here; offered: ${offered.join(", ")}`);
      state.format = offered[0] || "png";
    }
    select.value = state.format;
    select.addEventListener("change", () => {
      state.format = select.value;
      renderFrame();
    });
  }

  async function stop() {
    state.stopped = true;
    clearInterval(state.timer);
    clearInterval(state.watchTimer);
    if (state.inFlight) await state.inFlight;
  }

  window.addEventListener("pagehide", () => {
    if (state.session) {
      fetch(`/v1/sessions/${state.session}`, { method: "DELETE", headers: HEADERS, keepalive: true });
    }
  });

  // For tests and the console: the page's state and its two actions.
  window.sphrenderViewer = { state, refreshStatus, renderFrame, stop, watch, pollWatched };

  async function start() {
    $("spin").checked = params.get("spin") === "1";
    bindMouse();
    state.timer = setInterval(pollStatus, 1000);
    await pollStatus();
    try {
      await chooseFormats();
    } catch (error) {
      showError(String(error.message || error));
    }
    await renderFrame();
  }

  start();
})();
