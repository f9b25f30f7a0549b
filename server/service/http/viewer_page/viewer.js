// The sphrender viewer: live service status and the built-in demo orbited with the mouse.
//
// Plain JavaScript, no framework. The demo streams over the stream protocol on a WebSocket
// (PROTOCOL.md §10), as a browser frontend would:
//   GET  /v1/demo/frame          the demo's particles as one FRAME message (arrays + its scene)
//   WS   /v1/stream              HELLO {scene, mode: "latest"} -> WELCOME; then per camera change
//        FRAME {id, arrays, scene: {camera: {eye}, output: {format}}} + the demo's payload ->
//        IMAGE (drawn) or DROPPED (superseded by a newer frame: latest-frame-wins)
// and the HTTP API for the rest:
//   GET  /v1/status, /v1/info                       every second / once
//   WS   /v1/sessions/{id}/watch                     another session's images (any transport),
//        pushed as they come while that session is the one watched
// With a token, open /?token=...: the server sets a cookie that authorises these requests and
// the WebSocket upgrade (the X-Sphrender-Viewer header is required with it on POST and DELETE).
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
    socket: null, // the WebSocket once WELCOME came, else null
    connecting: null, // the promise of the WELCOME being waited for
    demo: null, // {arrays, payload, scene}: the demo frame from /v1/demo/frame
    helloScene: null,
    nextId: 0,
    sent: new Map(), // frame id -> the FRAME's scene override, until its answer
    inFlight: 0,
    dropped: 0,
    dirty: false,
    frames: 0,
    statusUpdates: 0,
    stopped: false,
    lastBody: null,
    timer: null,
    watch: null, // the id of the session watched instead of the demo, or null
    watchSocket: null,
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
    const wanted = sessions.filter((s) => !s.demo && s.latest_format && s.id !== state.session);
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

  // Another session's images, pushed on a WebSocket (GET /v1/sessions/{id}/watch) as they come.
  function openWatch(id) {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const socket = new WebSocket(`${scheme}://${location.host}/v1/sessions/${id}/watch`);
    socket.binaryType = "arraybuffer";
    socket.onmessage = async (event) => {
      const { type, header, payload } = decodeMessage(event.data);
      if (id !== state.watch) return;
      if (type === TYPE.GOODBYE) {
        showError(`session ${id.slice(0, 8)} ended`);
        return;
      }
      if (type !== TYPE.IMAGE) return;
      const blob = new Blob([payload], { type: `image/${header.format}` });
      await draw(blob);
      const canvas = $("live");
      canvas.dataset.source = id;
      canvas.dataset.image = String(header.image);
      $("frame-info").textContent =
        `session ${id.slice(0, 8)}, image ${header.image}: ` +
        `${canvas.width}x${canvas.height}, ${blob.size} bytes`;
      showError("");
    };
    socket.onclose = (event) => {
      if (id === state.watch && event.code !== 1000) showError(closeText(event));
    };
    return socket;
  }

  function watch(id) {
    state.watch = id === "demo" ? null : id;
    if (state.watchSocket) state.watchSocket.close(1000, "watching another");
    state.watchSocket = null;
    $("hint").hidden = state.watch !== null;
    $("source").value = id;
    if (state.watch) {
      state.watchSocket = openWatch(state.watch);
    } else {
      $("live").dataset.source = "demo";
      renderFrame();
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

  // -- the stream protocol over WebSocket (PROTOCOL.md §2 framing, §10 transport) -----------------

  const TYPE = {
    HELLO: 0x01,
    FRAME: 0x02,
    BYE: 0x03,
    WELCOME: 0x81,
    IMAGE: 0x82,
    ERROR: 0x83,
    DROPPED: 0x84,
    GOODBYE: 0x85,
  };
  // Frames unanswered at once: one rendering, one waiting; a newer one supersedes the waiting.
  const MAX_IN_FLIGHT = 2;

  // magic "SPHR", version 1, type, flags 0, header length, payload length (little-endian).
  function encodeMessage(type, header, payload) {
    const head = new TextEncoder().encode(JSON.stringify(header));
    const body = payload || new Uint8Array(0);
    const out = new Uint8Array(16 + head.length + body.length);
    const view = new DataView(out.buffer);
    out.set([0x53, 0x50, 0x48, 0x52, 1, type], 0);
    view.setUint16(6, 0, true);
    view.setUint32(8, head.length, true);
    view.setUint32(12, body.length, true);
    out.set(head, 16);
    out.set(body, 16 + head.length);
    return out;
  }

  function decodeMessage(buffer) {
    const view = new DataView(buffer);
    const headerLength = view.getUint32(8, true);
    const text = new TextDecoder().decode(new Uint8Array(buffer, 16, headerLength));
    return {
      type: view.getUint8(5),
      header: headerLength ? JSON.parse(text) : {},
      payload: new Uint8Array(buffer, 16 + headerLength),
    };
  }

  async function loadDemo() {
    const demo = decodeMessage(await (await api("GET", "/v1/demo/frame")).arrayBuffer());
    const scene = demo.header.scene || {};
    state.demo = { arrays: demo.header.arrays, payload: demo.payload.slice(), scene };
  }

  function connect() {
    if (state.connecting) return state.connecting;
    state.connecting = (async () => {
      if (!state.demo) await loadDemo();
      const scene = state.demo.scene;
      state.helloScene = {
        ...scene,
        image: { ...(scene.image || {}), width: state.width, height: state.height },
      };
      const scheme = location.protocol === "https:" ? "wss" : "ws";
      const socket = new WebSocket(`${scheme}://${location.host}/v1/stream`, "sphrender.stream.v1");
      socket.binaryType = "arraybuffer";
      await new Promise((resolve, reject) => {
        const hello = { scene: state.helloScene, mode: "latest", max_in_flight: MAX_IN_FLIGHT };
        socket.onopen = () => socket.send(encodeMessage(TYPE.HELLO, hello));
        socket.onclose = (event) => reject(new Error(closeText(event)));
        socket.onmessage = (event) => {
          const message = decodeMessage(event.data);
          if (message.type === TYPE.WELCOME) {
            state.session = message.header.session;
            state.orbit = state.orbit || orbitFrom(message.header.scene.camera);
            resolve();
          } else {
            onAnswer(message);
          }
        };
      });
      socket.onmessage = (event) => onAnswer(decodeMessage(event.data));
      socket.onclose = (event) => closed(socket, event);
      state.socket = socket;
    })();
    state.connecting.catch(() => {}).then(() => {
      state.connecting = null;
    });
    return state.connecting;
  }

  function closeText(event) {
    return `stream closed (${event.code}${event.reason ? ": " + event.reason : ""})`;
  }

  function closed(socket, event) {
    if (state.socket !== socket) return;
    state.socket = null; // the next frame opens a new session
    state.sent.clear();
    state.inFlight = 0;
    if (event.code !== 1000) showError(closeText(event));
  }

  function onAnswer(message) {
    const { type, header } = message;
    if (type === TYPE.ERROR) {
      showError(`${header.field ? header.field + ": " : ""}${header.error} (${header.code})`);
    }
    if (type === TYPE.GOODBYE || header.id === null || header.id === undefined) return;
    const scene = state.sent.get(header.id);
    state.sent.delete(header.id);
    state.inFlight = Math.max(0, state.inFlight - 1);
    if (type === TYPE.IMAGE) {
      drawImage(message, scene).then(next, (error) => showError(String(error.message || error)));
      return;
    }
    if (type === TYPE.DROPPED) state.dropped += 1;
    next();
  }

  async function drawImage(message, scene) {
    const { header, payload } = message;
    const blob = new Blob([payload], { type: `image/${header.format}` });
    await draw(blob);
    state.lastBody = JSON.stringify({ scene });
    state.frames += 1;
    const canvas = $("live");
    canvas.dataset.frames = String(state.frames);
    canvas.dataset.session = state.session;
    canvas.dataset.source = "demo";
    const render = Object.entries(header.timings_ms || {})
      .filter(([name]) => name !== "queue" && name !== "encode")
      .reduce((sum, [, ms]) => sum + Number(ms || 0), 0);
    $("frame-info").textContent =
      `frame ${state.frames}: ${canvas.width}x${canvas.height} ${header.format}, ` +
      `${blob.size} bytes, rendered in ${render.toFixed(0)} ms, ${state.dropped} superseded`;
    showError("");
  }

  function next() {
    if (state.stopped || state.watch) return;
    if (state.dirty || $("spin").checked) {
      if ($("spin").checked && !state.dirty) state.orbit.yaw += 0.03;
      requestAnimationFrame(renderFrame);
    }
  }

  // Send the demo from the current eye; with MAX_IN_FLIGHT unanswered, only remember to.
  async function renderFrame() {
    if (state.watch || state.stopped) return;
    if (!state.socket) {
      try {
        await connect();
      } catch (error) {
        showError(String(error.message || error));
        return;
      }
    }
    if (state.inFlight >= MAX_IN_FLIGHT) {
      state.dirty = true;
      return;
    }
    state.dirty = false;
    const id = state.nextId++;
    const scene = { camera: { eye: eye() }, output: { format: state.format } };
    const header = { id, arrays: state.demo.arrays, scene };
    state.sent.set(id, scene);
    state.inFlight += 1;
    state.socket.send(encodeMessage(TYPE.FRAME, header, state.demo.payload));
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

  function stop() {
    state.stopped = true;
    clearInterval(state.timer);
  }

  window.addEventListener("pagehide", () => {
    if (state.socket) {
      state.socket.send(encodeMessage(TYPE.BYE, {}));
      state.socket.close(1000, "page closed");
    }
  });

  // For tests and the console: the page's state and its two actions.
  window.sphrenderViewer = { state, refreshStatus, renderFrame, stop, watch };

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
    renderFrame();
  }

  start();
})();
