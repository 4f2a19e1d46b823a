// A page of another site in the operator's browser: Debian's chromium,
// driven by playwright-core. tests/tests/hal_sim_hostile_page.rs starts
// hal-sim in a network namespace, adds a second address on the namespace's
// side of its TAP, and runs this script inside the namespace:
//
//   node hostile.js DEVICE_URL PAGE_ADDRESS
//
// It serves hostile.html from http://PAGE_ADDRESS:8000/ (node's http, in
// this process), opens it in chromium with the device in its query, and
// waits for the page to post what it tried and what the browser let it
// see (/report). Meanwhile it records every request the browser sends to
// the device and the device's answer, as chromium's network log has them
// (playwright's events, and the DevTools protocol's for the CORS
// preflights, which playwright does not report). It prints one line of
// JSON: the page's report and that log, which the Rust test checks; the
// device behind it, the test checks itself. Exit status 1, with the reason
// on stderr, when the page never reports.
'use strict';

const fs = require('fs');
const http = require('http');
const path = require('path');
const { chromium } = require('playwright-core');

const [deviceUrl, pageAddress] = process.argv.slice(2);
if (!pageAddress) {
  console.error('usage: node hostile.js DEVICE_URL PAGE_ADDRESS');
  process.exit(2);
}

const CHROMIUM = '/usr/bin/chromium';
const PAGE_PORT = 8000;
// The page's whole run: about 20 attempts of at most 5 s each, most far shorter.
const REPORT_MS = 60000;

const device = new URL(deviceUrl).origin;
const html = fs.readFileSync(path.join(__dirname, 'hostile.html'));

// The other site: the page, and its report coming home.
function serve() {
  let reported;
  const report = new Promise((resolve) => (reported = resolve));
  const server = http.createServer((request, response) => {
    if (request.method == 'GET' && new URL(request.url, 'http://x').pathname == '/') {
      response.writeHead(200, { 'Content-Type': 'text/html; charset=utf-8' });
      response.end(html);
    } else if (request.method == 'POST' && request.url == '/report') {
      let body = '';
      request.on('data', (chunk) => (body += chunk));
      request.on('end', () => {
        response.writeHead(204);
        response.end();
        reported(body);
      });
    } else {
      response.writeHead(404);
      response.end();
    }
  });
  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(PAGE_PORT, pageAddress, () => resolve({ server, report }));
  });
}

async function main(browser, report) {
  const page = await browser.newPage();
  const errors = [];
  page.on('pageerror', (error) => errors.push(error.message));
  const console_ = [];
  page.on('console', (message) => console_.push(`${message.type()}: ${message.text()}`));

  // Every request to the device, in the order the page made them; what
  // was sent and what came back is read once the page is done: `status` is
  // the device's answer as chromium reports it (null when it reports none:
  // never sent, or withheld by CORS or ORB), `origin` and `content_type`
  // the fields sent (null when chromium's log has none for the request).
  const toDevice = [];
  page.on('request', (request) => {
    if (request.url().startsWith(device + '/')) toDevice.push(request);
  });
  // What chromium put on the wire, which only the DevTools protocol shows
  // for the page's own requests: the CORS preflights, and the header
  // fields chromium adds itself (Origin). Frames' navigations are not here.
  const wire = [];
  const byId = new Map();
  const cdp = await page.context().newCDPSession(page);
  await cdp.send('Network.enable');
  cdp.on('Network.requestWillBeSent', (event) => {
    if (!event.request.url.startsWith(device + '/')) return;
    const item = { method: event.request.method, path: new URL(event.request.url).pathname, preflight: event.request.method == 'OPTIONS' };
    byId.set(event.requestId, item);
    wire.push(item);
  });
  cdp.on('Network.requestWillBeSentExtraInfo', (event) => {
    const item = byId.get(event.requestId);
    if (item) item.headers = Object.fromEntries(Object.entries(event.headers).map(([k, v]) => [k.toLowerCase(), v]));
  });
  cdp.on('Network.responseReceived', (event) => {
    const item = byId.get(event.requestId);
    if (item) item.status = event.response.status;
  });
  cdp.on('Network.loadingFailed', (event) => {
    const item = byId.get(event.requestId);
    if (item) item.failure = event.errorText;
  });

  const url = `http://${pageAddress}:${PAGE_PORT}/?device=${encodeURIComponent(device)}`;
  const response = await page.goto(url);
  if (response.status() != 200) throw new Error(`GET ${url}: ${response.status()}`);
  let timer;
  const body = await Promise.race([
    report,
    new Promise((_, reject) => (timer = setTimeout(() => reject(new Error(`the page did not report within ${REPORT_MS} ms`)), REPORT_MS))),
  ]);
  clearTimeout(timer);
  // What the page wrote into its own document, the same report.
  const shown = await page.textContent('#report');
  // The wire's record of a request, when the protocol has one.
  const taken = new Set();
  const onWire = (method, path) => {
    const item = wire.find((w) => !w.preflight && !taken.has(w) && w.method == method && w.path == path);
    if (item) taken.add(item);
    return (item && item.headers) || {};
  };
  const sent = [];
  for (const request of toDevice) {
    const path = new URL(request.url()).pathname;
    const headers = { ...(await request.allHeaders().catch(() => ({}))), ...onWire(request.method(), path) };
    const response = await request.response().catch(() => null);
    const failure = request.failure();
    sent.push({
      method: request.method(),
      path,
      resource: request.resourceType(),
      origin: headers['origin'] || null,
      content_type: headers['content-type'] || null,
      body: request.postData(),
      status: response ? response.status() : null,
      failure: failure ? failure.errorText : null,
    });
  }
  const preflights = wire
    .filter((w) => w.preflight)
    .map((w) => ({
      method: w.method,
      path: w.path,
      origin: (w.headers && w.headers['origin']) || null,
      asks: (w.headers && w.headers['access-control-request-method']) || null,
      status: w.status || null,
      failure: w.failure || null,
    }));
  return { page_url: url, page: JSON.parse(body), shown_equal: shown == body, sent, preflights, page_errors: errors, console: console_ };
}

(async () => {
  let status = 0;
  const { server, report } = await serve();
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ['--headless', '--no-sandbox', '--disable-background-networking'],
  });
  try {
    console.log(JSON.stringify(await main(browser, report)));
  } catch (e) {
    console.error(`hostile: ${e.message}`);
    status = 1;
  } finally {
    await browser.close();
    server.close();
  }
  process.exit(status);
})();
