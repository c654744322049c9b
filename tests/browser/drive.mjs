// Drives the browser editor in headless Chromium (Debian's, or $CHROMIUM) for tests/browser.rs:
// loads the page with the token, moves the jawOpen slider through the page, and reports what
// changed, and times a ten-step drag; then loads it with a wrong token and reports the refusal;
// then, given a fourth URL (https, a server with a self-signed certificate), loads the page
// there and reports the first frame drawn over wss. Prints one JSON object.
import puppeteer from "puppeteer-core";

const [url, wrongUrl, screenshot, tlsUrl] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    // The TLS run's certificate is self-signed for the test.
    "--ignore-certificate-errors"],
});
const result = { consoleErrors: [] };
const timeout = 120_000;
try {
  const page = await browser.newPage();
  await page.setViewport({ width: 1200, height: 800 });
  page.on("console", (m) => { if (m.type() === "error") result.consoleErrors.push(m.text()); });
  page.on("pageerror", (e) => result.consoleErrors.push(String(e)));
  await page.goto(url);
  await page.waitForFunction(() => window.facesim.frames > 0 && window.facesim.positions, { timeout });
  // A sample of the canvas's pixels (every 7th), to see the picture change.
  const pixels = () => page.evaluate(() => {
    const canvas = document.getElementById("canvas");
    const gl = canvas.getContext("webgl2");
    const data = new Uint8Array(canvas.width * canvas.height * 4);
    gl.readPixels(0, 0, canvas.width, canvas.height, gl.RGBA, gl.UNSIGNED_BYTE, data);
    return Array.from(data.filter((_, i) => (i >> 2) % 7 === 0));
  });
  const before = await page.evaluate(() => ({
    index: facesim.frame.index, positions: Array.from(facesim.positions),
  }));
  const beforePixels = await pixels();
  await page.evaluate(() => {
    const s = document.getElementById("slider-jawOpen");
    s.value = "0.9";
    s.dispatchEvent(new Event("input"));
  });
  await page.waitForFunction(() => facesim.frame.codes.expression[0] === 0.9, { timeout });
  await new Promise((r) => setTimeout(r, 300));
  const after = await page.evaluate(() => ({
    index: facesim.frame.index,
    positions: Array.from(facesim.positions),
    stats: document.getElementById("stats").textContent,
    warning: document.getElementById("warning").textContent,
    error: document.getElementById("error").textContent,
    sliders: document.querySelectorAll("input[type=range]").length,
  }));
  const afterPixels = await pixels();
  result.frameBefore = before.index;
  result.frameAfter = after.index;
  result.movedCm = before.positions.reduce((m, v, i) => Math.max(m, Math.abs(v - after.positions[i])), 0);
  let changed = 0;
  for (let i = 0; i < beforePixels.length; i += 4) {
    if ([0, 1, 2].some((k) => Math.abs(beforePixels[i + k] - afterPixels[i + k]) > 24)) changed += 1;
  }
  result.pixelsChanged = changed;
  result.stats = after.stats;
  result.warning = after.warning;
  result.error = after.error;
  result.sliders = after.sliders;
  if (screenshot) await page.screenshot({ path: screenshot });
  // A drag through the page, back from 0.9 to 0 in ten steps, refinement off (as `facesim
  // bench editor` measures): per step, the time from the slider's input event to the first
  // frame of that value decoded and drawn.
  result.dragMs = await page.evaluate(async () => {
    const refine = document.getElementById("refine");
    if (refine.checked) refine.click();
    await new Promise((r) => setTimeout(r, 500));
    const s = document.getElementById("slider-jawOpen");
    const times = [];
    for (let k = 1; k <= 10; k++) {
      const w = Math.round((0.9 - 0.09 * k) * 100) / 100;
      const start = performance.now();
      s.value = String(w);
      s.dispatchEvent(new Event("input"));
      while (facesim.frame.codes.expression[0] !== w) await new Promise((r) => setTimeout(r, 1));
      times.push(performance.now() - start);
    }
    return times;
  });
  result.timing = await page.evaluate(() => facesim.timing);
  // Each heatmap colours the skin.
  const plain = await pixels();
  result.heatmapPixelsChanged = [];
  for (const option of await page.$$eval("#heatmap option", (os) => os.map((o) => o.value))) {
    if (option === "-1") continue;
    await page.select("#heatmap", option);
    const coloured = await pixels();
    let changed = 0;
    for (let i = 0; i < plain.length; i += 4) {
      if ([0, 1, 2].some((k) => Math.abs(plain[i + k] - coloured[i + k]) > 24)) changed += 1;
    }
    result.heatmapPixelsChanged.push(changed);
  }

  const wrong = await browser.newPage();
  await wrong.goto(wrongUrl);
  await wrong.waitForFunction(() => window.facesim.refused, { timeout });
  result.refused = await wrong.evaluate(() => window.facesim.refused);
  result.loginShown = await wrong.evaluate(() => !document.getElementById("login").hidden);

  if (tlsUrl) {
    const secure = await browser.newPage();
    secure.on("pageerror", (e) => result.consoleErrors.push(String(e)));
    await secure.goto(tlsUrl);
    await secure.waitForFunction(() => window.facesim.frames > 0 && window.facesim.positions, { timeout });
    result.tls = await secure.evaluate(() => ({
      protocol: location.protocol, socket: facesim.ws.url, frames: facesim.frames,
      deflated: facesim.deflated,
    }));
  }
} catch (e) {
  result.failure = String(e);
} finally {
  await browser.close();
}
console.log(JSON.stringify(result));
