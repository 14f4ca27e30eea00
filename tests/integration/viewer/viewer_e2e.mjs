// End-to-end test of the browser viewer (docs/viewer.md): fslam-server streams the synthetic room,
// fslam-gateway serves the page, Debian's chromium (headless, WebGL through SwiftShader) driven by
// puppeteer-core looks at it. Asserts that the canvas is not blank and changes as the map grows,
// that the Gaussian count shown is the server's, that a click on an object gives a mask with IoU
// >= 0.6 against the object's ground-truth label at that pose, and that a second browser sees the
// same map. Prints the update rate and frame rate. Exits 77 (skipped) when chromium, the bundle or
// puppeteer-core is missing.
//
//   node viewer_e2e.mjs --bin BUILD/bin --web BUILD/viewer --modules client/gateway/web
//       [--out DIR] [--frames N] [--rate HZ] [--weights F] [--room DIR] [--keep] [--time-scale S]
import { spawn, execFileSync } from "node:child_process";
import { createRequire } from "node:module";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";
import { readPng } from "./png.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, "..", "..", "..");
const args = Object.fromEntries(process.argv.slice(2).reduce((acc, a, i, all) => {
  if (a.startsWith("--")) acc.push([a.slice(2), all[i + 1] && !all[i + 1].startsWith("--") ? all[i + 1] : "1"]);
  return acc;
}, []));
const bin = path.resolve(args.bin || path.join(repo, "build", "bin"));
const web = path.resolve(args.web || path.join(repo, "build", "viewer"));
const modules = path.resolve(args.modules || path.join(repo, "client", "gateway", "web"));
const outDir = path.resolve(args.out || path.join(bin, "..", "test_output", "viewer"));
const frames = Number(args.frames || 40);
// The client is paused while the page draws its first map (step 3); the rate only keeps the map
// growing in small steps for the update-rate figure.
const rate = args.rate || "2";
const chromium = process.env.FSLAM_CHROMIUM || "/usr/bin/chromium";
// The deadlines of the waits for the server (until() and the stream's --timeout) are multiplied
// by $FSLAM_TEST_TIME_SCALE, else --time-scale (the build's default, tests/CMakeLists.txt: 4 under
// ASan, 8 under TSan, whose servers map that much slower).
const timeScale = Math.max(1, Number(process.env.FSLAM_TEST_TIME_SCALE || args["time-scale"] || 1));
const t0 = Date.now();
const log = (...m) => console.log(`[${((Date.now() - t0) / 1000).toFixed(1)} s]`, ...m);

function skip(why) {
  console.log(`SKIPPED: ${why}`);
  process.exit(77);
}
if (!fs.existsSync(chromium)) skip(`no chromium at ${chromium} (apt-get install chromium; deploy/setup.sh --test installs it)`);
if (!fs.existsSync(path.join(web, "index.html"))) skip(`no bundled page at ${web} (deploy/setup.sh bundles it with npm)`);
let puppeteer;
try {
  puppeteer = createRequire(path.join(modules, "package.json"))("puppeteer-core");
} catch {
  skip(`puppeteer-core not installed under ${modules} (npm ci there; deploy/setup.sh does it)`);
}
for (const b of ["fslam", "fslam-server", "fslam-gateway"]) {
  if (!fs.existsSync(path.join(bin, b))) throw new Error(`no ${b} in ${bin}: build first`);
}

const work = fs.mkdtempSync(path.join(os.tmpdir(), "fslam_viewer_e2e_"));
fs.mkdirSync(outDir, { recursive: true });
const env = { ...process.env, CYCLONEDDS_URI: `file://${path.join(repo, "configs", "dds", "loopback.xml")}` };
const prefix = `viewer${process.pid}`;
const children = [];
function start(name, file, argv) {
  const out = fs.openSync(path.join(work, `${name}.log`), "w");
  const child = spawn(file, argv, { env, stdio: ["ignore", out, out] });
  child.name = name;
  children.push(child);
  return child;
}
function stopAll() {
  for (const c of children.reverse()) if (c.exitCode === null) c.kill("SIGTERM");
}
process.on("exit", stopAll);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function until(what, fn, timeoutMs = 60000, periodMs = 250) {
  const end = Date.now() + timeoutMs * timeScale;
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
    await sleep(periodMs);
  }
}
const fslam = (...a) => execFileSync(path.join(bin, "fslam"), a, { env, encoding: "utf8", stdio: ["ignore", "pipe", "pipe"] });
function check(ok, what) {
  if (!ok) throw new Error(`FAILED: ${what}`);
  log(`ok: ${what}`);
}

let browser;
let failed = false;
try {
  // 1. The room, the weights, the server and the gateway.
  // --room DIR: a room synthesised before with the same --frames (re-runs by hand).
  const seq = args.room ? path.resolve(args.room) : path.join(work, "room");
  if (!args.room) fslam("synth", "--out", seq, "--frames", String(frames), "--seed", "1");
  let weights = args.weights || path.join(repo, "out", "autoencoder", "builtin.fae");
  if (!fs.existsSync(weights)) {
    // A smaller autoencoder of its own, made once per build folder (the demo's takes a minute).
    weights = path.join(bin, "..", "test_models", "viewer_autoencoder.fae");
    if (!fs.existsSync(weights)) {
      log("no out/autoencoder/builtin.fae: training a small autoencoder for the test");
      execFileSync("bash", [path.join(repo, "deploy", "make_builtin_autoencoder.sh"), "--out", weights,
        "--work", path.join(work, "ae"), "--frames", "6", "--steps", "1500", "--fslam", path.join(bin, "fslam")],
      { env, stdio: "ignore" });
    }
  }
  log(`room synthesised (${frames} frames), weights ${weights}`);
  // A long session lease: the test pauses its streaming client while the page catches up.
  const server = start("server", path.join(bin, "fslam-server"), ["--prefix", prefix,
    "--set", `features.autoencoder_path=${weights}`, "--set", "server.session_lease_s=900",
    // Mapping at normal priority, each keyframe in full and no idle optimisation: the map grows
    // per keyframe and holds still between, whatever else (headless chromium) loads the machine.
    // In real time a loaded CI machine mapped the first keyframe only as the stream ended.
    "--set", "realtime=false"]);
  const portFile = path.join(work, "port");
  const gateway = start("gateway", path.join(bin, "fslam-gateway"), ["--prefix", prefix, "--port", "0",
    "--port-file", portFile, "--web", web, "--verbose"]);
  const port = Number(await until("the gateway's port", () => {
    if (gateway.exitCode !== null || server.exitCode !== null) throw new Error("the gateway or the server exited at start");
    return fs.existsSync(portFile) && fs.readFileSync(portFile, "utf8").trim();
  }));
  const url = `http://127.0.0.1:${port}/?size=640x480`;
  log(`gateway at ${url}`);

  // 2. Chromium, headless; WebGL through SwiftShader (no GPU here).
  browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true,
    userDataDir: fs.mkdtempSync(path.join(work, "chromium-")),
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
      "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
      "--window-size=960,540"],
  });
  const external = [];
  async function openViewer(context) {
    const page = await context.newPage();
    await page.setViewport({ width: 960, height: 540 });
    page.on("pageerror", (e) => log("page error:", String(e)));
    page.on("request", (r) => { if (!r.url().startsWith(`http://127.0.0.1:${port}/`) && !r.url().startsWith("ws://127.0.0.1") && !r.url().startsWith("data:") && !r.url().startsWith("blob:")) external.push(r.url()); });
    page.setDefaultTimeout(180000);  // a loaded 2-core machine without a GPU is slow, not broken
    await page.goto(url, { waitUntil: "load", timeout: 180000 });
    return page;
  }
  const page = await openViewer(browser);
  const gl = await page.evaluate(() => {
    const c = document.createElement("canvas").getContext("webgl2");
    if (!c) return null;
    const e = c.getExtension("WEBGL_debug_renderer_info");
    return e ? c.getParameter(e.UNMASKED_RENDERER_WEBGL) : c.getParameter(c.RENDERER);
  });
  check(gl !== null, `WebGL2 in headless chromium: ${gl}`);

  // 3. Stream the room; the page shows the map as it grows.
  const stream = start("stream", path.join(bin, "fslam"), ["stream", "--dataset", seq, "--prefix", prefix,
    "--session", "e2e", "--map", "room", "--rate", rate, "--policy", "queue",  // every frame mapped: the same map on any machine
    "--window", "2", "--timeout", String(900 * timeScale)]);
  const snapshot = () => page.evaluate(() => {
    const src = document.getElementById("view");
    const c = document.createElement("canvas");
    c.width = 160; c.height = 120;
    const ctx = c.getContext("2d");
    ctx.drawImage(src, 0, 0, 160, 120);
    const d = ctx.getImageData(0, 0, 160, 120).data;
    const grey = [];
    let lit = 0;
    for (let i = 0; i < d.length; i += 4) {
      const g = (d[i] + d[i + 1] + d[i + 2]) / 3;
      grey.push(g);
      if (g > 8) ++lit;
    }
    const el = document.getElementById("gaussian-count");
    return { grey, lit: lit / (160 * 120), count: Number(el.dataset.count), version: Number(el.dataset.version) };
  });
  // The server's map row from `fslam status`: { count, version }, or null while it has none.
  // (null too when no status came in time: the server reports at 1 Hz, a loaded one later.)
  const serverMap = () => {
    let status;
    try { status = fslam("status", "--prefix", prefix); } catch { return null; }
    const header = status.split("\n").find((l) => l.startsWith("map "));
    const row = status.split("\n").find((l) => l.startsWith("room "));
    if (!header || !row) return null;
    const names = header.trim().split(/\s+/), cells = row.trim().split(/\s+/);
    const [count, version] = ["gaussians", "version"].map((c) => Number(cells[names.indexOf(c)]));
    return { count, version, row };
  };
  // The first snapshot must be of a small map whatever the machine's speed (a loaded CI machine
  // drew its first map after the stream had ended, so the map could not grow any more): pause
  // the client after its first frames, let mapping and the page catch up, then go on.
  await until("the client's first frames", () => {
    if (stream.exitCode !== null) throw new Error("fslam stream ended before its fourth frame");
    const sent = [...fs.readFileSync(path.join(work, "stream.log"), "utf8").matchAll(/\[stream\] (\d+)\/\d+ /g)];
    return sent.length > 0 && Number(sent[sent.length - 1][1]) >= 4;
  }, 120000, 100);
  stream.kill("SIGUSR1");  // fslam stream pauses before its next frame
  await until("the client to pause", () => fs.readFileSync(path.join(work, "stream.log"), "utf8").includes("paused before frame"), 60000, 250);
  await until("the server's first Gaussians", () => {
    const m = serverMap();
    return m && m.count > 0;
  }, 240000, 500);
  let settled = null;
  await until("the paused map to settle", async () => {
    const m = serverMap();
    const same = settled && m && m.version === settled.version;
    settled = m;
    return same;
  }, 120000, 1000);
  const first = await until(`the page to show map version ${settled.version}`, async () => {
    const s = await snapshot();
    return s.version === settled.version && s.lit > 0.02 ? s : null;
  }, 180000, 500);
  const resumed = await page.evaluate(() => ({ ...window.fslamViewer.state.stats }));
  stream.kill("SIGUSR1");
  await page.screenshot({ path: path.join(outDir, "viewer_growing.jpg"), type: "jpeg", quality: 85 });
  check(first.lit > 0.02, `canvas not blank at map version ${first.version} (${first.count} Gaussians, ${(100 * first.lit).toFixed(1)} % of pixels lit)`);
  const later = await until("a later map version", async () => {
    const s = await snapshot();
    // Grown by a seventh at least: one keyframe's few hundred new splats can leave this
    // viewpoint's pixels almost as they were (mean grey change 0.5-0.7 measured), a flaky test.
    return s.version > first.version && s.count >= 1.15 * first.count ? s : null;
  }, 240000, 500);
  await sleep(1500);  // a few frames of the new splats
  const grown = await snapshot();
  let diff = 0;
  for (let i = 0; i < grown.grey.length; ++i) diff += Math.abs(grown.grey[i] - first.grey[i]);
  diff /= grown.grey.length;
  check(diff > 1, `canvas changes as the map grows: version ${first.version} -> ${later.version}, ${first.count} -> ${later.count} Gaussians, mean grey change ${diff.toFixed(1)}`);

  await until("the stream to finish", () => stream.exitCode !== null, 240000, 500);
  check(stream.exitCode === 0, "fslam stream finished");
  // 4. The count shown is the server's (the map is final now the session is closed).
  const { count: serverCount, version: serverVersion, row } = await until("the server's status", serverMap, 60000, 1000);
  let last = null;
  const shown = await until("the final version in the page", async () => {
    last = await snapshot();
    return last.version === serverVersion ? last : null;
  }, 240000, 500).catch((e) => {
    throw new Error(`${e.message}: the page shows version ${last.version} (${last.count} Gaussians), fslam status: ${row}`);
  });
  check(shown.count === serverCount, `page shows ${shown.count} Gaussians at version ${shown.version}; the server's status: ${serverCount} at ${serverVersion}`);
  const figures = await page.evaluate(() => ({ ...window.fslamViewer.state.stats, fps: window.fslamViewer.state.fps }));

  // 5. A second browser on the same map at once.
  const context2 = await browser.createBrowserContext();
  const page2 = await openViewer(context2);
  const second = await until("the map in a second browser", () => page2.evaluate(() => {
    const el = document.getElementById("gaussian-count");
    return Number(el.dataset.count) > 0 ? { count: Number(el.dataset.count), version: Number(el.dataset.version) } : null;
  }), 60000, 250);
  check(second.count === serverCount && second.version === serverVersion, `second browser shows the same map (${second.count} Gaussians, version ${second.version})`);

  // 6. Click on an object at a ground-truth pose; the mask against the object's label there.
  const gt = fs.readFileSync(path.join(seq, "groundtruth.txt"), "utf8").split("\n").filter((l) => l && !l.startsWith("#"));
  const k = Math.floor(frames * 0.75);
  const [, tx, ty, tz, qx, qy, qz, qw] = gt[k].trim().split(/\s+/).map(Number);
  const intr = fs.readFileSync(path.join(seq, "intrinsics.txt"), "utf8").split("\n").find((l) => l && !l.startsWith("#")).trim().split(/\s+/).map(Number);
  const view = { t: [tx, ty, tz], q: [qx, qy, qz, qw], fx: intr[0], fy: intr[1], cx: intr[2], cy: intr[3], width: intr[4], height: intr[5] };
  await page.evaluate((v) => window.fslamViewer.setView(v), view);
  await sleep(1500);
  await page.screenshot({ path: path.join(outDir, "viewer_map.jpg"), type: "jpeg", quality: 85 });
  const stamp = fs.readFileSync(path.join(seq, "rgb.txt"), "utf8").split("\n").filter((l) => l && !l.startsWith("#"))[k].split(/\s+/)[1];
  const labels = readPng(fs.readFileSync(path.join(seq, "labels", "instance", path.basename(stamp))));
  const structure = new Set(fs.readFileSync(path.join(seq, "instances.txt"), "utf8").split("\n")
    .filter((l) => l && !l.startsWith("#")).map((l) => l.split(/\s+/))
    .filter(([, , name]) => /wall|floor|ceiling/.test(name)).map(([id]) => Number(id)));
  // The object pixel farthest from its outline (image border counted as outline), as a user clicks.
  const W = labels.width, H = labels.height, L = labels.data;
  const dist = new Float32Array(W * H);
  for (let y = 0; y < H; ++y) for (let x = 0; x < W; ++x) {
    const i = y * W + x, inside = (xx, yy) => xx >= 0 && yy >= 0 && xx < W && yy < H && L[yy * W + xx] === L[i];
    dist[i] = inside(x, y) ? Math.min(inside(x - 1, y) ? dist[i - 1] + 1 : 1, inside(x, y - 1) ? dist[i - W] + 1 : 1) : 0;
  }
  for (let y = H - 1; y >= 0; --y) for (let x = W - 1; x >= 0; --x) {
    const i = y * W + x, inside = (xx, yy) => xx >= 0 && yy >= 0 && xx < W && yy < H && L[yy * W + xx] === L[i];
    dist[i] = Math.min(dist[i], inside(x + 1, y) ? dist[i + 1] + 1 : 1, inside(x, y + 1) ? dist[i + W] + 1 : 1);
  }
  let best = -1;
  for (let i = 0; i < W * H; ++i) if (L[i] > 0 && !structure.has(L[i]) && (best < 0 || dist[i] > dist[best])) best = i;
  check(best >= 0, `an object to click in frame ${k}: instance ${L[best]}, ${dist[best]} px from its outline`);
  const object = L[best], u = best % W, v = Math.floor(best / W);
  await page.click("input[name=tool][value=point]");
  const box = await (await page.$("#view")).boundingBox();
  await page.mouse.click(box.x + u + 0.5, box.y + v + 0.5);
  const seg = await until("the click's mask", () => page.evaluate(() => {
    const s = window.fslamViewer.state;
    if (s.lastError) return { error: s.lastError };
    return s.lastSegment && s.lastSegment.mode === "points" ? { width: s.lastSegment.width, height: s.lastSegment.height, alpha: Array.from(s.lastSegment.alpha) } : null;
  }), 120000, 500);
  check(!seg.error, `segment request answered${seg.error ? ": " + seg.error : ""}`);
  await sleep(500);
  await page.screenshot({ path: path.join(outDir, "viewer_click.jpg"), type: "jpeg", quality: 85 });
  let inter = 0, union = 0;
  for (let i = 0; i < W * H; ++i) {
    const a = seg.alpha[i] > 0, b = L[i] === object;
    if (a && b) ++inter;
    if (a || b) ++union;
  }
  const iou = union > 0 ? inter / union : 0;
  check(seg.width === W && seg.height === H && iou >= 0.6, `click at (${u}, ${v}) on instance ${object}: mask IoU ${iou.toFixed(3)} with its ground-truth label (>= 0.6)`);

  // 7. Promptless instances, for the screenshot.
  await page.click("#promptless");
  const inst = await until("promptless instances", () => page.evaluate(() => {
    const s = window.fslamViewer.state.lastSegment;
    return s && s.mode === "promptless" ? s.instances : null;
  }), 120000, 500);
  await sleep(500);
  await page.screenshot({ path: path.join(outDir, "viewer_instances.jpg"), type: "jpeg", quality: 85 });
  check(inst > 1, `promptless: ${inst} instances in view`);
  check(external.length === 0, `nothing fetched from outside the gateway${external.length ? ": " + external.join(", ") : ""}`);

  // 8. Figures for docs/benchmarks.md.
  await page.evaluate((v) => window.fslamViewer.setView(v), view);
  const fps = await page.evaluate(() => window.fslamViewer.measureFps(8000));
  // The update rate after the pause: versions the page took in from the resumed stream.
  const span = (figures.last - resumed.last) / 1000, taken = figures.versions - resumed.versions;
  log(`figures: ${taken} map versions in ${span.toFixed(1)} s after the pause while streaming at ${rate} Hz ` +
    `(${span > 0 ? (taken / span).toFixed(2) : "-"} versions/s), ${(figures.bytes / Math.max(1, figures.versions) / 1024).toFixed(0)} KiB per update on average, ` +
    `last ${(figures.lastBytes / 1024).toFixed(0)} KiB (${serverCount} Gaussians x 32 B), ` +
    `page build of the last version ${figures.buildMs.toFixed(0)} ms; ${fps.toFixed(1)} fps at 640x480 drawing every frame (SwiftShader)`);
  await context2.close();
  console.log("viewer e2e: 1 passed, 0 failed");
} catch (e) {
  failed = true;
  console.log(String(e && e.stack ? e.stack : e));
  for (const c of children) {
    const f = path.join(work, `${c.name}.log`);
    if (fs.existsSync(f)) console.log(`--- ${c.name}.log (tail)\n${fs.readFileSync(f, "utf8").split("\n").slice(-25).join("\n")}`);
  }
  console.log("viewer e2e: 0 passed, 1 failed");
} finally {
  if (browser) await browser.close().catch(() => {});
  stopAll();
  await sleep(500);
  if (!args.keep && !failed) fs.rmSync(work, { recursive: true, force: true });
  else console.log(`work folder kept: ${work}`);
  log(`screenshots in ${outDir}`);
}
process.exit(failed ? 1 : 0);
