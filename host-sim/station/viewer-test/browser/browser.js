// The map as a person sees it: Lichtblick's web build (the open-source Foxglove Studio) in headless
// Chromium, on the live view of `host-sim demo --view` and on its `--record` recording, with the committed
// layout (host-sim/station/foxglove-layout.json). Run through `run.sh` beside this file (it installs what
// is missing); it writes screenshots and exits non-zero when a check fails.
//
// Usage: node browser.js --host-sim PATH --lichtblick lichtblick-web-vX.tar.gz --shots DIR [--phrase tree]
//
// What it does and checks, in order:
//   1. serves the unpacked Lichtblick and the recording on 127.0.0.1 (Range requests: serve.js) and starts
//      `host-sim demo --view 127.0.0.1:0 --record demo.mcap`;
//   2. live: opens Lichtblick on the demo's WebSocket while the robot maps, imports the layout through the
//      app's own menu (View → Import layout from file…), waits for the run to end (the demo then keeps
//      serving), types a query phrase in the Parameters panel, and takes `live.png`;
//   3. reloads the page (a client reconnecting after the run) and checks the whole map again;
//   4. recording: opens demo.mcap as a remote file (`recording-open.png`: the file must open on a map), then
//      seeks by clicking the timeline at the middle and at the end (`recording-middle.png`,
//      `recording-end.png`; at the end the legend must count the demo's last scene);
//   5. stops the demo with SIGINT (it must exit cleanly).
// Pixel checks on each 3D panel (the screenshot's pixels of its canvas): the classes panel shows each class
// that holds at least 2 % of the voxels in its legend colour (shading allowed: the colour times a factor),
// class colours are most of the map's pixels, few are black (outlines) or grey (undecoded); the heat panel
// is coloured, not grey. The app's alerts list ("Alerts", its problems panel) must be empty, and no panel
// may log an error.
"use strict";
const { spawn, spawnSync } = require("child_process");
const fs = require("fs");
const os = require("os");
const path = require("path");
const readline = require("readline");
const { PNG } = require("pngjs");
const puppeteer = require("puppeteer-core");
const { serve } = require("./serve");

function arg(name, fallback) {
  const i = process.argv.indexOf(`--${name}`);
  return i >= 0 ? process.argv[i + 1] : fallback;
}
const hostSim = arg("host-sim");
const tarball = arg("lichtblick");
const shots = arg("shots");
const phrase = arg("phrase", "tree");
const chromium = arg("chromium", "/usr/bin/chromium");
const layoutPath = path.join(__dirname, "..", "..", "foxglove-layout.json");
const layout = fs.readFileSync(layoutPath, "utf8");
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const results = [];
function check(name, ok, detail) {
  results.push({ name, ok, detail });
  console.log(`${ok ? "ok  " : "FAIL"} ${name}: ${detail}`);
}

// ---- the demo --------------------------------------------------------------------------------------

function startDemo(work, recording) {
  const child = spawn(
    hostSim,
    ["demo", "--out", path.join(work, "out"), "--view", "127.0.0.1:0", "--record", recording],
    { stdio: ["ignore", "pipe", "inherit"] },
  );
  const lines = [];
  const waiters = [];
  readline.createInterface({ input: child.stdout }).on("line", (line) => {
    lines.push(line);
    if (line.startsWith("viewer:")) console.log(`  demo | ${line}`);
    for (const w of [...waiters]) {
      const m = w.re.exec(line);
      if (m) {
        waiters.splice(waiters.indexOf(w), 1);
        w.resolve(m);
      }
    }
  });
  const exited = new Promise((resolve) => child.on("exit", (code, signal) => resolve({ code, signal })));
  const waitFor = (re, ms) =>
    new Promise((resolve, reject) => {
      const m = lines.map((l) => re.exec(l)).find(Boolean);
      if (m) return resolve(m);
      waiters.push({ re, resolve });
      setTimeout(() => reject(new Error(`the demo never printed ${re}`)), ms);
      exited.then(() => setTimeout(() => reject(new Error(`the demo exited before printing ${re}`)), 100));
    });
  return { child, lines, exited, waitFor };
}

// ---- the app ---------------------------------------------------------------------------------------

async function openApp(browser, url) {
  const page = await browser.newPage();
  // The layout file the app's "Import layout from file…" asks for (headless: no file dialog).
  await page.evaluateOnNewDocument((text) => {
    window.showOpenFilePicker = async () => [
      {
        kind: "file",
        name: "foxglove-layout.json",
        getFile: async () => new File([text], "foxglove-layout.json", { type: "application/json" }),
      },
    ];
  }, layout);
  page.on("pageerror", (e) => console.log(`  page error: ${String(e).slice(0, 200)}`));
  await page.goto(url, { waitUntil: "load" });
  await page.waitForSelector('[data-testid="AppMenuButton"]', { timeout: 60000 });
  return page;
}

async function clickMenuItem(page, text) {
  for (const item of await page.$$('[role="menuitem"]')) {
    const t = await item.evaluate((e) => e.innerText.trim());
    if (t.startsWith(text)) {
      await item.click();
      return true;
    }
  }
  return false;
}

async function importLayout(page) {
  await page.click('[data-testid="AppMenuButton"]');
  await sleep(500);
  if (!(await clickMenuItem(page, "View"))) throw new Error("no View menu");
  await sleep(500);
  if (!(await clickMenuItem(page, "Import layout from file"))) throw new Error("no 'Import layout from file…'");
  await sleep(3000);
}

async function leftSidebar(page, open) {
  const shown = (await page.$('[data-testid="alerts-left"]')) !== null;
  if (shown !== open) {
    await page.click('[data-testid="left-sidebar-button"]');
    await sleep(500);
  }
}

/** The app's alerts (its problems list) and the panels' logged errors. */
async function problems(page) {
  await leftSidebar(page, true);
  await page.click('[data-testid="alerts-left"]');
  await sleep(700);
  const alerts = await page.evaluate(() => {
    const text = document.body.innerText;
    return text.includes("No alerts found") ? [] : [text.split("Alerts")[1]?.slice(0, 400) ?? "?"];
  });
  await leftSidebar(page, false);
  const logged = [];
  for (const button of await page.$$('button[title^="Show logs"]')) {
    await button.click();
    await sleep(400);
    const entries = await page.evaluate(() =>
      document.body.innerText.split("\n").filter((l) => /^\[(ERROR|WARN)/.test(l.trim())),
    );
    logged.push(...entries);
    await button.click();
    await sleep(200);
  }
  return { alerts, logged };
}

/** The legend as the Table panel shows it: class, colour, voxels. */
async function legend(page) {
  return page.evaluate(() => {
    const rows = [...document.querySelectorAll("tr")].map((tr) =>
      [...tr.querySelectorAll("td,th")].map((c) => c.innerText.trim()),
    );
    const head = rows.find((r) => r.includes("class") && r.includes("colour"));
    if (!head) return [];
    const [ic, io, iv] = ["class", "colour", "voxels"].map((k) => head.indexOf(k));
    return rows
      .filter((r) => r !== head && /^#[0-9a-f]{6}$/.test(r[io] || ""))
      .map((r) => ({ name: r[ic], hex: r[io], voxels: Number(r[iv]) }));
  });
}

/** Type `word` into the Parameters panel's `query` field; the submit button. */
async function setQuery(page, word) {
  const input = await page.waitForSelector('textarea[data-testid^="validated-input"]', { timeout: 30000 });
  await input.click();
  await input.evaluate((e) => e.select());
  await page.keyboard.press("Backspace");
  await page.keyboard.type(JSON.stringify(word));
  const submit = await page.waitForSelector('button[aria-label="Submit change"]', { timeout: 10000 }).catch(() => null);
  if (!submit) {
    const value = await input.evaluate((e) => e.value);
    throw new Error(`the Parameters panel offers no submit button (its field holds ${value})`);
  }
  return submit;
}

/** Click `submit` and time until the panel at `rect` repaints (5 % of the pixels of its middle 240 × 160
 * change: a small clip, so that each poll is short); ms, or null. */
async function timeRepaint(page, rect, submit) {
  const clip = { x: rect.x + rect.width / 2 - 120, y: rect.y + rect.height / 2 - 80, width: 240, height: 160 };
  const before = PNG.sync.read(await page.screenshot({ clip }));
  const t0 = Date.now();
  await submit.click();
  while (Date.now() - t0 < 20000) {
    const now = PNG.sync.read(await page.screenshot({ clip }));
    let changed = 0;
    for (let i = 0; i < now.data.length; i += 4) {
      const d = [0, 1, 2].reduce((s, j) => s + Math.abs(now.data[i + j] - before.data[i + j]), 0);
      if (d > 40) changed++;
    }
    if (changed > 0.05 * (now.data.length / 4)) return Date.now() - t0;
  }
  return null;
}

/** The 3D panels' canvases, left to right then top to bottom (the largest canvas of each panel). */
async function panels(page) {
  const rects = await page.evaluate(() =>
    [...document.querySelectorAll("canvas")]
      .map((c) => c.getBoundingClientRect())
      .filter((r) => r.width > 200 && r.height > 150)
      .map((r) => ({ x: r.x, y: r.y, width: r.width, height: r.height })),
  );
  rects.sort((a, b) => a.x - b.x || a.y - b.y);
  return rects;
}

// ---- pixels ----------------------------------------------------------------------------------------

const hexRgb = (h) => [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16));

/** Classify a panel's pixels: background, class colours (shaded: colour × k), black, grey, other. */
function pixels(png, classes, background) {
  const counts = { all: 0, background: 0, map: 0, black: 0, grey: 0, classed: 0, perClass: new Map() };
  const cols = classes.map((c) => ({ name: c.name, rgb: hexRgb(c.hex) }));
  for (let i = 0; i < png.data.length; i += 4) {
    const p = [png.data[i], png.data[i + 1], png.data[i + 2]];
    counts.all++;
    const max = Math.max(...p);
    const min = Math.min(...p);
    if (p.every((v, j) => Math.abs(v - background[j]) <= 14) || (max - min < 10 && min > 150)) {
      counts.background++; // the panel's background and its grid
      continue;
    }
    counts.map++;
    if (max < 45) counts.black++;
    let best = null;
    for (const c of cols) {
      const cc = c.rgb.reduce((s, v) => s + v * v, 0) || 1;
      const k = c.rgb.reduce((s, v, j) => s + v * p[j], 0) / cc;
      const res = Math.hypot(...p.map((v, j) => v - k * c.rgb[j]));
      if (k > 0.35 && k < 1.45 && res < 28 && (!best || res < best.res)) best = { name: c.name, res };
    }
    if (best) {
      counts.classed++;
      counts.perClass.set(best.name, (counts.perClass.get(best.name) || 0) + 1);
    } else if (max - min < 16) {
      counts.grey++;
    }
  }
  return counts;
}

async function shoot(page, name) {
  const file = path.join(shots, name);
  await page.screenshot({ path: file });
  console.log(`  wrote ${file}`);
  return PNG.sync.read(fs.readFileSync(file));
}

function crop(png, r) {
  const out = new PNG({ width: Math.floor(r.width), height: Math.floor(r.height) });
  PNG.bitblt(png, out, Math.floor(r.x), Math.floor(r.y), out.width, out.height, 0, 0);
  return out;
}

const pct = (a, b) => (b ? (100 * a) / b : 0).toFixed(1);

/** `partial`: a map mid-run, sparse, whose many cube edges blend with the background (neither class colour
 * nor grey): it need fill less of the panel and fewer of its pixels are pure class colours. */
function checkClasses(label, png, rect, classes, partial = false) {
  const [fill, classed] = partial ? [0.05, 0.6] : [0.15, 0.75];
  const c = pixels(crop(png, rect), classes, [0xe8, 0xe8, 0xe8]);
  const total = classes.reduce((s, x) => s + x.voxels, 0);
  const wanted = classes.filter((x) => x.voxels >= 0.02 * total);
  const seen = wanted.filter((x) => (c.perClass.get(x.name) || 0) >= 0.001 * c.map);
  const shares = [...c.perClass].map(([n, k]) => `${n} ${pct(k, c.map)} %`).join(", ");
  check(
    `${label}: the map fills the classes panel`,
    c.map >= fill * c.all,
    `${pct(c.map, c.all)} % of the panel's pixels are the map (≥ ${100 * fill} %)`,
  );
  check(
    `${label}: class colours`,
    seen.length === wanted.length && c.classed >= classed * c.map,
    `${seen.length} of ${wanted.length} classes with ≥ 2 % of the voxels seen in their legend colour; ` +
      `${pct(c.classed, c.map)} % of the map's pixels are class colours (≥ ${100 * classed} %): ${shares}`,
  );
  check(
    `${label}: not black or grey`,
    c.black <= 0.05 * c.map && c.grey <= 0.1 * c.map,
    `black ${pct(c.black, c.map)} % (≤ 5 %), grey ${pct(c.grey, c.map)} % (≤ 10 %) of the map's pixels`,
  );
}

function checkHeat(label, png, rect) {
  const c = pixels(crop(png, rect), [], [0xe8, 0xe8, 0xe8]);
  check(
    `${label}: the heat panel is coloured`,
    c.map >= 0.05 * c.all && c.grey <= 0.2 * c.map && c.black <= 0.05 * c.map,
    `map ${pct(c.map, c.all)} % of the panel (≥ 5 %); grey ${pct(c.grey, c.map)} % (≤ 20 %), black ` +
      `${pct(c.black, c.map)} % (≤ 5 %) of its pixels`,
  );
}

async function checkProblems(label, page) {
  const p = await problems(page);
  check(
    `${label}: no problems`,
    p.alerts.length === 0 && !p.logged.some((l) => l.startsWith("[ERROR")),
    `alerts: ${p.alerts.length ? p.alerts.join(" | ") : "none"}; panel logs: ` +
      `${p.logged.length ? p.logged.join(" | ") : "no errors or warnings"}`,
  );
}

/** Seek by clicking the timeline at `fraction` of its width (at 1: then step forward to the very end). */
async function seek(page, fraction) {
  const bar = await page.evaluate(() => {
    const s = document.querySelector('[role="slider"]')?.parentElement?.getBoundingClientRect();
    return s && s.width > 200 ? { x: s.x, y: s.y, width: s.width, height: s.height } : null;
  });
  const vh = page.viewport().height;
  const r = bar || { x: 8, y: vh - 67, width: page.viewport().width - 16, height: 10 };
  await page.mouse.click(r.x + Math.min(r.width - 2, fraction * r.width), r.y + r.height / 2);
  await sleep(2000);
  if (fraction >= 1) {
    for (let i = 0; i < 20; i++) {
      await page.click('[data-testid="seek-forward-button"]').catch(() => {});
      await sleep(250);
    }
  }
  await page.mouse.move(r.x + r.width / 2, r.y - 300); // no timeline tooltip over the panels
  await sleep(6000);
}

// ---- the run ---------------------------------------------------------------------------------------

async function main() {
  if (!hostSim || !tarball || !shots) {
    console.error("usage: node browser.js --host-sim PATH --lichtblick TGZ --shots DIR [--phrase WORD]");
    process.exit(2);
  }
  fs.mkdirSync(shots, { recursive: true });
  const work = fs.mkdtempSync(path.join(os.tmpdir(), "latentbki-browser-"));
  const untar = spawnSync("tar", ["xzf", tarball, "-C", work]);
  if (untar.status !== 0) throw new Error(`cannot unpack ${tarball}: ${untar.stderr}`);
  const root = fs
    .readdirSync(work)
    .map((d) => path.join(work, d))
    .find((d) => fs.existsSync(path.join(d, "index.html")));
  if (!root) throw new Error(`${tarball} holds no folder with index.html`);
  const recording = path.join(work, "demo.mcap");
  const server = await serve(root, { "/demo.mcap": recording });
  const http = `http://127.0.0.1:${server.address().port}`;
  const demo = startDemo(work, recording);
  const browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true,
    userDataDir: path.join(work, "profile"),
    defaultViewport: { width: 1600, height: 1000 },
    args: [
      "--no-sandbox",
      "--use-angle=swiftshader",
      "--enable-unsafe-swiftshader",
      "--disable-background-networking",
      "--disable-component-update",
      "--disable-sync",
      "--no-first-run",
      "--disable-quic",
    ],
  });
  try {
    const ws = (await demo.waitFor(/^viewer: serving ws:\/\/127\.0\.0\.1:(\d+)/, 120000))[1];
    // Live, while the robot maps.
    const page = await openApp(browser, `${http}/?ds=foxglove-websocket&ds.url=ws://127.0.0.1:${ws}`);
    await importLayout(page);
    await leftSidebar(page, false);
    const last = Number((await demo.waitFor(/^viewer: recorded .*; last scene (\d+) voxels/, 900000))[1]);
    await demo.waitFor(/^viewer: the run is over; still serving/, 60000);
    await sleep(4000);
    const classes = await legend(page);
    check(
      "live: the legend names the classes",
      classes.length > 0 && classes.every((c) => c.name && c.hex),
      classes.map((c) => `${c.name} ${c.hex} ${c.voxels}`).join(", ") || "no legend table",
    );
    let [map, heat] = await panels(page);
    const submit = await setQuery(page, phrase);
    const repaint = await timeRepaint(page, heat, submit);
    check(
      `live: the heat panel follows a query typed in the viewer`,
      repaint !== null,
      repaint === null
        ? "no repaint within 20 s"
        : `"${phrase}" submitted → heat panel repainted in ${repaint} ms (polling screenshots of its middle; ` +
            `SwiftShader's software WebGL)`,
    );
    await sleep(3000);
    let png = await shoot(page, "live.png");
    [map, heat] = await panels(page);
    checkClasses("live", png, map, classes);
    checkHeat(`live, query "${phrase}"`, png, heat);
    await checkProblems("live", page);
    // A client reconnecting after the run gets the whole scene.
    await page.reload({ waitUntil: "load" });
    await sleep(12000);
    png = PNG.sync.read(await page.screenshot());
    [map, heat] = await panels(page);
    checkClasses("live, reconnected", png, map, classes);
    await checkProblems("live, reconnected", page);
    await page.close();
    // The recording (closed when the run ended): it opens on a map, and seeks.
    const rec = await openApp(browser, `${http}/?ds=remote-file&ds.url=${http}/demo.mcap`);
    await sleep(8000);
    await leftSidebar(rec, false);
    const recClasses = await legend(rec);
    png = await shoot(rec, "recording-open.png");
    [map] = await panels(rec);
    const first = pixels(crop(png, map), recClasses, [0xe8, 0xe8, 0xe8]);
    check(
      "recording: opens on a map",
      first.classed > 0 && recClasses.length > 0,
      `${first.classed} class-coloured pixels at the file's start; legend ${recClasses.map((c) => c.voxels).join("/")} voxels`,
    );
    await seek(rec, 0.5);
    png = await shoot(rec, "recording-middle.png");
    [map] = await panels(rec);
    checkClasses("recording, seek to the middle", png, map, await legend(rec), true);
    await seek(rec, 1.0);
    png = await shoot(rec, "recording-end.png");
    [map, heat] = await panels(rec);
    const endClasses = await legend(rec);
    const endVoxels = endClasses.reduce((s, c) => s + c.voxels, 0);
    check(
      "recording, seek to the end: the final map",
      endVoxels === last,
      `the legend counts ${endVoxels} voxels at the end, the demo's last scene held ${last}`,
    );
    checkClasses("recording, seek to the end", png, map, endClasses);
    checkHeat("recording, the demo's query", png, heat);
    await checkProblems("recording", rec);
  } finally {
    await browser.close();
    demo.child.kill("SIGINT");
    const { code } = await demo.exited;
    check("demo: exits cleanly on SIGINT", code === 0, `exit code ${code}`);
    server.close();
    fs.rmSync(work, { recursive: true, force: true });
  }
  const failed = results.filter((r) => !r.ok);
  console.log(`browser-check: ${results.length - failed.length} of ${results.length} checks passed`);
  process.exit(failed.length ? 1 : 0);
}

if (require.main === module) {
  main().catch((e) => {
    console.error(`browser-check: FAILED: ${e.stack || e}`);
    process.exit(1);
  });
}
module.exports = { openApp, importLayout, leftSidebar, legend, setQuery, timeRepaint, panels, problems };
